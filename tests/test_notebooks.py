"""Every notebook runs top to bottom in a kernel, in the documentation site's build, and its page
shows what it computed: the plots and printed values (``mkdocs build --strict`` executes them)."""

import re
import subprocess
import sys
from pathlib import Path

import jupytext
import pytest

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.py"))
PLOTS = {"01_forward_model", "03_fit_photo", "04_profiles_for_renderers", "05_calibrated_model"}  # notebooks that draw


def test_every_notebook_is_a_jupytext_notebook():
    assert any(p.name == "01_forward_model.py" for p in NOTEBOOKS)
    for path in NOTEBOOKS:
        assert len(jupytext.read(path).cells) > 3, path


@pytest.fixture(scope="module")
def executed_site(tmp_path_factory):
    site = tmp_path_factory.mktemp("site")
    env = {"NO_MKDOCS_2_WARNING": "1", "PATH": str(Path(sys.executable).parent), "HOME": str(site), "MPLBACKEND": "Agg",
           "SKINFIT_DOCS_EXECUTE": "true"}
    result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                            cwd=ROOT, capture_output=True, text=True, env=env, timeout=1800)
    assert result.returncode == 0, result.stderr[-5000:]
    return site


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_each_notebook_page_shows_its_outputs(path, executed_site):
    page = (executed_site / "notebooks" / path.stem / "index.html").read_text()
    outputs = re.findall(r'class="[^"]*jp-OutputArea-output[^"]*"', page)
    assert len(outputs) >= 2, "the page shows no outputs: the notebook was not executed"
    assert "Traceback (most recent call last)" not in page
    if path.stem in PLOTS:
        assert "data:image/png;base64," in page, "a notebook that draws shows no plot"
