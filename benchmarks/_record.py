"""What every saved benchmark result records about where and when it was made."""

from __future__ import annotations

import os
import platform
import subprocess
import time
from pathlib import Path

import jax

ROOT = Path(__file__).resolve().parents[1]


def git_commit() -> str:
    """HEAD, marked when the working tree's code differs from it (results files that a benchmark
    run rewrites, under benchmarks/results/, do not count: the next benchmark of the same run still
    measures HEAD's code)."""
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", ".", ":(exclude)benchmarks/results"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()
        return commit + (" (working tree modified)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def provenance() -> dict:
    """Date, machine and commit for a results file."""
    return {
        "date": time.strftime("%Y-%m-%d"),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__} on {jax.default_backend()}",
        "git_commit": git_commit(),
    }
