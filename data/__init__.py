"""Sample inputs shipped with the package (the demo photo); see README.md here."""
