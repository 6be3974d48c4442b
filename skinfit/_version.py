"""The package version (one place, read by the exports' metadata)."""

__version__ = "0.1.0"
