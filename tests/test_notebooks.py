"""Every notebook runs top to bottom as a script (jupytext percent format)."""

import os
import subprocess
import sys
from pathlib import Path

import jupytext
import pytest

pytestmark = pytest.mark.slow  # each notebook runs for up to a minute

NOTEBOOKS = sorted((Path(__file__).resolve().parent.parent / "notebooks").glob("*.py"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    assert jupytext.read(path).cells, "not a jupytext notebook"
    env = dict(os.environ, MPLBACKEND="Agg")
    result = subprocess.run([sys.executable, str(path)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]


def test_there_is_a_forward_model_notebook():
    assert any(p.name == "01_forward_model.py" for p in NOTEBOOKS)
