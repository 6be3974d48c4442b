"""The README's two newcomer commands stay true (CI runs the test one verbatim; the docs' index shows
the same two), and every table of measured results in the README or the docs is its saved file."""

from pathlib import Path

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


def test_readme_benchmark_tables_are_the_saved_benchmark_output():
    block = _block("bench")
    assert block == (ROOT / "benchmarks" / "results" / "pareto" / "summary.md").read_text().strip()


def test_readme_calibration_summary_is_the_saved_calibration_report():
    block = _block("calibration")
    assert block == (ROOT / "benchmarks" / "results" / "calibration_summary.md").read_text().strip()


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


def test_readme_measured_fit_table_is_the_saved_benchmark_output():
    block = _block("fit-measured")
    assert block == (ROOT / "benchmarks" / "results" / "fit_measured.md").read_text().strip()


def test_readme_real_input_table_is_the_saved_benchmark_output():
    block = _block("fit-photos")
    assert block == (ROOT / "benchmarks" / "results" / "fit_photos.md").read_text().strip()


def test_readme_renderer_table_is_the_saved_benchmark_output():
    block = _block("renderers")
    assert block == (ROOT / "benchmarks" / "results" / "renderers.md").read_text().strip()


def test_forward_model_table_is_the_saved_benchmark_output():
    block = _block("forward-model")
    assert block == (ROOT / "benchmarks" / "results" / "forward_model.md").read_text().strip()


def test_image_solver_table_is_the_saved_benchmark_output():
    block = _block("fit-image")
    assert block == (ROOT / "benchmarks" / "results" / "fit_image.md").read_text().strip()
