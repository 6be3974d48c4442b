"""skinfit's benchmarks (``python -m benchmarks.<name>``); each script's docstring says what it measures.

The benchmarks run without skinfit's persistent compilation cache and its disk cache of colour
tables (``SKINFIT_COMPILATION_CACHE=0``, ``SKINFIT_DISK_CACHE=0``, unless the caller set them): every
"first call" they report is a cold compilation and build, not a read of what an earlier run left on
disk. ``benchmarks.fit_realistic`` and ``benchmarks.fit_photos`` (a fresh process, caches warm)
measure the caches' own effect.
"""

import os

os.environ.setdefault("SKINFIT_COMPILATION_CACHE", "0")
os.environ.setdefault("SKINFIT_DISK_CACHE", "0")
