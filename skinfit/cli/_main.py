"""The ``skinfit`` command line: spectra, profile tables, fits and the demo job.

Usage errors (bad arguments, out-of-range values) print one line and exit with status 2.
"""

from __future__ import annotations

import os
import sys

import jax

from .._validate import SkinfitInputError
from ._parser import build_parser


def _enable_compilation_cache() -> None:
    """Keep compiled programs between runs (a fit compiles for about 15 s on a 2-core CPU).

    The folder is ``$SKINFIT_CACHE_DIR``, else ``$XDG_CACHE_HOME/skinfit/jax`` (``~/.cache``);
    a folder the user configured for JAX already wins. Only the command line does this: a library
    should not change global JAX settings.
    """
    if jax.config.jax_compilation_cache_dir:
        return
    folder = os.environ.get("SKINFIT_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "skinfit", "jax"
    )
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError:
        return  # read-only home: run uncached
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    _enable_compilation_cache()
    try:
        return args.run(args)
    except SkinfitInputError as err:
        print(f"skinfit {args.command}: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"skinfit {args.command}: error: {err}", file=sys.stderr)
        return 1
