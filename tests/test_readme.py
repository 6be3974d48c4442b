"""The README's two newcomer commands stay true (CI runs the test one verbatim; the docs' index shows
the same two), and every table of measured results in the README or the docs is its saved file."""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _command_lines(text):
    return [line.strip() for line in text.splitlines() if line.strip().startswith("python3 -m venv")]


def test_ci_runs_the_readme_test_command_verbatim():
    readme = _command_lines((ROOT / "README.md").read_text())
    ci = _command_lines((ROOT / ".ci" / "run").read_text())
    assert len(readme) == 2, "the README gives a newcomer exactly two commands"
    assert ci == [readme[1]]
    assert readme[1].endswith("pytest") and "[test]" in readme[1]
    assert "\npytest -m slow" in (ROOT / ".ci" / "run").read_text()  # and the slow tier after it


def _block(marker: str) -> str:
    """The text between <!-- marker:start --> and <!-- marker:end --> in the README or a docs page
    (exactly one of them holds it)."""
    found = [text.split(f"<!-- {marker}:start -->\n", 1)[1].split(f"\n<!-- {marker}:end -->", 1)[0]
             for text in (path.read_text() for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))])
             if f"<!-- {marker}:start -->" in text]
    assert len(found) == 1, f"{marker}: found in {len(found)} files"
    return found[0]


def test_the_docs_index_shows_the_readme_commands():
    assert _command_lines((ROOT / "docs" / "index.md").read_text()) == _command_lines((ROOT / "README.md").read_text())


def test_readme_main_command_runs_the_demo():
    assert _command_lines((ROOT / "README.md").read_text())[0].endswith("skinfit demo")




def test_calibration_summary_describes_the_shipped_model():
    import json

    shipped = json.loads((ROOT / "spectra" / "calibrated_model.json").read_text())
    record = json.loads((ROOT / "benchmarks" / "results" / "calibration.json").read_text())
    for name, value in record["constants"].items():
        assert abs(_constant(shipped["constants"], name) - value) <= 1e-12 * max(1.0, abs(value)), name


def _constant(constants, dotted):
    node = constants
    for part in dotted.split("."):
        node = node[part]
    return node


# every generated table of the README and the docs: <!-- marker:start --> ... <!-- marker:end -->
# holds exactly the results file its benchmark wrote (python -m benchmarks.sync_docs copies them in)
from benchmarks.sync_docs import GENERATED_BLOCKS  # noqa: E402


@pytest.mark.parametrize("marker, results_file", GENERATED_BLOCKS, ids=[m for m, _ in GENERATED_BLOCKS])
def test_each_generated_table_is_its_saved_benchmark_output(marker, results_file):
    assert _block(marker) == (ROOT / "benchmarks" / "results" / results_file).read_text().strip()
