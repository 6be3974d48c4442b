"""The ``skinfit`` command line: spectra, profile tables, fits and the demo job.

Usage errors (bad arguments, out-of-range values) print one line and exit with status 2.
"""

from __future__ import annotations

import sys

from .._validate import SkinfitInputError
from ._parser import build_parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except SkinfitInputError as err:
        print(f"skinfit {args.command}: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"skinfit {args.command}: error: {err}", file=sys.stderr)
        return 1
