"""Saved benchmark results and the code they describe.

Every file in ``benchmarks/results/`` records when and where it was made. A file that records the
commit it was made at is compared with the code it depends on: where that code changed after the
commit, the test warns (``StaleResultWarning``, shown in the test summary) that the file should be
regenerated with its script. A file with no commit warns too.
"""

import ast
import json
import subprocess
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"

# results file -> (the script that writes it, the code its numbers depend on)
DEPENDS_ON = {
    "calibration.json": ("benchmarks/calibrate_model.py", ["skinfit/model", "skinfit/fit"]),
    "calibration_check.json": ("benchmarks/calibrate_model.py", ["skinfit/model", "skinfit/fit"]),
    "calibration_methods.json": ("benchmarks/calibrate_model.py", ["skinfit/model", "skinfit/fit"]),
    "capture_skin_rule.json": ("benchmarks/capture_skin_rule.py", ["skinfit/model", "skinfit/fit", "skinfit/colorimetry", "skinfit/io"]),
    "fit_image.json": ("benchmarks/fit_image.py", ["skinfit/fit", "skinfit/colorimetry"]),
    "fit_image_tones.json": ("benchmarks/fit_image_tones.py", ["skinfit/model", "skinfit/fit", "skinfit/colorimetry"]),
    "fit_image_box.json": ("benchmarks/fit_image_box.py", ["skinfit/model", "skinfit/fit", "skinfit/colorimetry"]),
    "fit_measured.json": ("benchmarks/fit_measured.py", ["skinfit/model", "skinfit/fit"]),
    "fit_nist.json": ("benchmarks/fit_nist.py", ["skinfit/model", "skinfit/fit"]),
    "fit_realistic.json": ("benchmarks/fit_realistic.py", ["skinfit/model", "skinfit/fit"]),
    "fit_noise.json": ("benchmarks/fit_noise.py", ["skinfit/model", "skinfit/fit"]),
    "fit_photos.json": ("benchmarks/fit_photos.py", ["skinfit/fit", "skinfit/colorimetry", "skinfit/io"]),
    "fit_spectra.json": ("benchmarks/fit_spectra.py", ["skinfit/model", "skinfit/fit"]),
    "forward_model.json": ("benchmarks/forward_model.py", ["skinfit/model", "skinfit/export/_profile_tables.py"]),
    "layered_renders.json": ("benchmarks/layered_renders.py", ["skinfit/model", "skinfit/export/_layered.py", "skinfit/export/_mitsuba_layered.py",
                                                               "skinfit/export/_mitsuba.py"]),
    "medium_table.json": ("benchmarks/build_medium_table.py", ["skinfit/model", "skinfit/export/_media.py"]),
    "profile_fits.json": ("benchmarks/profile_fits.py", ["skinfit/model", "skinfit/export", "skinfit/colorimetry", "spectra"]),
    "renderers.json": ("benchmarks/renderers.py", ["skinfit/model", "skinfit/export"]),
    "segment_faces.json": ("benchmarks/segment_faces.py", ["skinfit/segmentation"]),
    "solver_diagnosis.json": ("benchmarks/solver_diagnosis.py", ["skinfit/model", "skinfit/fit"]),
    "spectra_starts.json": ("benchmarks/spectra_starts.py", ["skinfit/model", "skinfit/fit"]),
    "transport_fit.json": ("benchmarks/transport_fit.py", ["skinfit/model", "skinfit/fit", "skinfit/colorimetry"]),
    "transport_fit_h100.json": ("benchmarks/transport_fit.py", ["skinfit/model", "skinfit/fit"]),
    "transport_table.json": ("benchmarks/build_transport_table.py", ["skinfit/model/_transport.py", "skinfit/model/_transport_table.py"]),
    "white_balance.json": ("benchmarks/white_balance.py", ["skinfit/model", "skinfit/fit", "skinfit/colorimetry", "skinfit/io"]),
}


class StaleResultWarning(UserWarning):
    """A saved result may no longer describe the code."""


def _git(*args) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()


def recorded_commit(record: dict) -> str | None:
    """The commit a results file was made at (its ``git_commit`` or ``commit``, without the dirty mark)."""
    commit = record.get("git_commit") or record.get("commit")
    return commit.split()[0].removesuffix("-dirty") if commit and commit != "unknown" else None


def changed_since(commit: str, paths: list[str]) -> list[str]:
    """The files among ``paths`` (files or folders) whose code commits after ``commit`` changed: a
    Python file whose docstrings and comments alone changed does not count (its syntax tree without
    docstrings is the same at ``commit`` and at HEAD); a file moved, added or removed does."""
    touched = sorted({line for line in _git("log", "--format=", "--name-only", f"{commit}..HEAD", "--", *paths).splitlines() if line})
    return [path for path in touched if not (path.endswith(".py") and _same_code(commit, "HEAD", path))]


def _code(source: str) -> str | None:
    """The module's syntax tree without docstrings (comments are not in it), or None where it does not parse."""
    try:
        tree = ast.parse(source)
    except SyntaxError:
        return None
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body
                and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree)


def _same_code(old: str, new: str, path: str) -> bool:
    try:
        before, after = _git("show", f"{old}:{path}"), _git("show", f"{new}:{path}")
    except subprocess.CalledProcessError:
        return False  # added, removed or moved
    return _code(before) is not None and _code(before) == _code(after)


def test_every_results_file_is_listed_and_says_when_and_where_it_was_made():
    saved = {p.name for p in RESULTS.glob("*.json")}
    assert saved == set(DEPENDS_ON), f"list new results files in DEPENDS_ON: {sorted(saved ^ set(DEPENDS_ON))}"
    for name, (script, _) in DEPENDS_ON.items():
        record = json.loads((RESULTS / name).read_text())
        assert record.get("date") and record.get("machine"), name
        assert (ROOT / script).is_file(), script


def test_saved_results_warn_when_their_code_changed_after_them():
    try:
        _git("rev-parse", "HEAD")
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    for name, (script, paths) in DEPENDS_ON.items():
        commit = recorded_commit(json.loads((RESULTS / name).read_text()))
        if commit is None:
            warnings.warn(f"{name} records no commit: regenerate it with {script}", StaleResultWarning)
            continue
        try:
            changed = changed_since(commit, paths)
        except subprocess.CalledProcessError:
            warnings.warn(f"{name}: commit {commit[:10]} is not in this clone's history", StaleResultWarning)
            continue
        if changed:
            warnings.warn(f"{name} ({commit[:10]}) predates changes to {len(set(changed))} of its files "
                          f"(e.g. {sorted(set(changed))[0]}): regenerate it with {script}", StaleResultWarning)


def test_the_staleness_check_sees_a_change():
    # the mechanism can fail: from the repository's first commit, the model has changed
    try:
        first = _git("rev-list", "--max-parents=0", "HEAD").splitlines()[0]
    except (OSError, subprocess.CalledProcessError, IndexError):
        pytest.skip("not a git checkout")
    assert changed_since(first, ["skinfit"])
    assert changed_since(_git("rev-parse", "HEAD"), ["skinfit"]) == []
    # a docstring or comment is not code; a changed constant is
    module = '"""Doc."""\n\ndef f(x):\n    """What f does."""\n    return 2 * x  # twice\n'
    assert _code(module) == _code(module.replace("What f does.", "What f returns.").replace("# twice", "# double"))
    assert _code(module) != _code(module.replace("2 * x", "3 * x"))
    assert recorded_commit({"git_commit": "abc123 (working tree modified)"}) == "abc123"
    assert recorded_commit({"commit": "b4fceff-dirty"}) == "b4fceff"


def test_the_shipped_calibration_is_reproduced_within_its_standard_errors():
    """``calibrate_model --check`` recalibrated on later code: the shipped model must be what that
    check compared with, and every constant must land within one of its standard errors (the outer
    problem is flat along the epidermis's scattering, so the digits are not expected to repeat), with
    the same held-out error to 0.01 CIEDE2000."""
    check = json.loads((RESULTS / "calibration_check.json").read_text())
    shipped = json.loads((ROOT / "spectra" / "calibrated_model.json").read_text())["calibration"]["constants"]
    assert set(check["constants"]) == set(shipped)
    for name, entry in check["constants"].items():
        assert entry["shipped"] == pytest.approx(shipped[name], rel=1e-12), name
        assert abs(entry["difference_in_standard_errors"]) <= 1.0, (name, entry)
    for part in check["held_out"].values():
        assert abs(part["delta_e2000_median"]["recalibrated"] - part["delta_e2000_median"]["shipped"]) <= 0.01
        assert part["max_steps"]["recalibrated"] == 0
