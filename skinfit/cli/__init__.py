"""The ``skinfit`` command line: the parser and commands, the batch job that writes one fitted image to
a folder, Dask distribution and the plots the commands write.
"""

from ._arguments import parse_radii, parse_wavelengths
from ._main import main
from ._parser import build_parser

__all__ = [
    "build_parser",
    "main",
    "parse_radii",
    "parse_wavelengths",
]
