"""The documentation site builds without a warning (``mkdocs build --strict``; here with the notebooks
shown unexecuted, which ``tests/test_notebooks.py`` runs in the slow tier), lists every page,
and holds every section of the model notes that a docstring cites."""

import re
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent


def test_the_site_builds_strictly(tmp_path):
    result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")], cwd=ROOT,
                            capture_output=True, text=True, env={"NO_MKDOCS_2_WARNING": "1", "PATH": "", "HOME": str(tmp_path),
                                                                 "SKINFIT_DOCS_EXECUTE": "false"}, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert (tmp_path / "site" / "api" / "index.html").read_text().count('id="skinfit.') > 100  # the reference was generated
    assert "Media for path tracers" in (tmp_path / "site" / "notebooks" / "04_profiles_for_renderers" / "index.html").read_text()


class _ConfigLoader(yaml.SafeLoader):
    """mkdocs.yml as data: its ``!ENV`` settings (environment variables) read as None."""


_ConfigLoader.add_constructor("!ENV", lambda loader, node: None)


def _pages(nav):
    for entry in nav:
        value = entry if isinstance(entry, str) else next(iter(entry.values()))
        yield from (_pages(value) if isinstance(value, list) else [value])


def test_every_page_and_notebook_is_in_the_navigation():
    config = yaml.load((ROOT / "mkdocs.yml").read_text(), Loader=_ConfigLoader)
    pages = {p.name for p in (ROOT / "docs").glob("*.md")} | {f"notebooks/{p.name}" for p in (ROOT / "notebooks").glob("*.py")}
    assert set(_pages(config["nav"])) == pages
    assert {p.name for p in (ROOT / "docs" / "notebooks").iterdir()} == {p.name for p in (ROOT / "notebooks").glob("*.py")}


def test_the_model_notes_hold_every_cited_section():
    cited = set()
    for path in [*(ROOT / "skinfit").rglob("*.py"), *(ROOT / "tests").rglob("*.py")]:
        cited |= set(re.findall(r"model notes,? (\d+(?:\.\d+)?)", path.read_text()))
    headings = set(re.findall(r"^#{2,3} (\d+(?:\.\d+)?)\.? ", (ROOT / "docs" / "model-notes.md").read_text(), flags=re.M))
    assert cited and cited <= headings, sorted(cited - headings)
