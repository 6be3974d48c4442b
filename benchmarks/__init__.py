"""skinfit's benchmarks (``python -m benchmarks.<name>``); each script's docstring says what it measures.

The benchmarks run without skinfit's persistent compilation cache (``SKINFIT_COMPILATION_CACHE=0``,
unless the caller set it): every "first call" they report is a cold compilation, not a read of what
an earlier run left on disk. ``benchmarks.fit_realistic`` measures the cache's own effect.
"""

import os

os.environ.setdefault("SKINFIT_COMPILATION_CACHE", "0")
