"""Chromophore data tables shipped with skinfit (see README.md)."""
