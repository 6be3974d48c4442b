"""Which saved benchmark results predate the code they describe: a report a maintainer asks for.

Run: python -m benchmarks.stale [--all]

Every file in ``benchmarks/results/`` records when, where and at which commit it was made. Each is
listed here with the script that writes it and the code its numbers depend on; a file is stale when
a commit after its own changed that code (a Python file whose docstrings or comments alone changed
does not count). The report lists the stale files, what changed and the command that regenerates
each; the test suite checks only that every file is listed and records its provenance.
"""

from __future__ import annotations

import argparse
import ast
import json
import subprocess
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

# results file -> (the script that writes it, the code its numbers depend on)
DEPENDS_ON = {
    "calibration.json": ("benchmarks/calibrate_model.py", ["skinfit/model", "skinfit/fit"]),
    "calibration_check.json": ("benchmarks/calibrate_model.py", ["skinfit/model", "skinfit/fit"]),
    "calibration_methods.json": ("benchmarks/calibrate_model.py", ["skinfit/model", "skinfit/fit"]),
    "capture_skin_rule.json": ("benchmarks/capture_skin_rule.py", ["skinfit/model", "skinfit/fit", "skinfit/colorimetry", "skinfit/io"]),
    "face_blur.json": ("benchmarks/face_blur.py", ["skinfit/model", "skinfit/fit", "skinfit/colorimetry", "skinfit/export/_blur.py"]),
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



@dataclass(frozen=True)
class Staleness:
    """One results file against the code it depends on."""

    name: str
    script: str
    commit: str | None  # None: the file records no commit
    changed: tuple[str, ...]  # code files changed after ``commit``
    in_history: bool = True  # False: ``commit`` is not in this clone

    @property
    def stale(self) -> bool:
        return self.commit is None or not self.in_history or bool(self.changed)

    def line(self) -> str:
        command = f"python -m {self.script.removesuffix('.py').replace('/', '.')}"
        if self.commit is None:
            return f"{self.name}: records no commit; regenerate with {command}"
        if not self.in_history:
            return f"{self.name}: commit {self.commit[:10]} is not in this clone's history"
        if not self.changed:
            return f"{self.name} ({self.commit[:10]}): current"
        shown = ", ".join(self.changed[:3]) + (f" and {len(self.changed) - 3} more" if len(self.changed) > 3 else "")
        return f"{self.name} ({self.commit[:10]}): {len(self.changed)} files changed since ({shown}); regenerate with {command}"


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


def staleness(name: str) -> Staleness:
    """``name`` (a file in benchmarks/results/) against HEAD."""
    script, paths = DEPENDS_ON[name]
    commit = recorded_commit(json.loads((RESULTS / name).read_text()))
    if commit is None:
        return Staleness(name, script, None, ())
    try:
        return Staleness(name, script, commit, tuple(changed_since(commit, paths)))
    except subprocess.CalledProcessError:
        return Staleness(name, script, commit, (), in_history=False)


def report(names=None) -> list[Staleness]:
    """Every listed results file (or ``names``) against HEAD."""
    return [staleness(name) for name in (names or DEPENDS_ON)]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--all", action="store_true", help="list current files too")
    args = parser.parse_args(argv)
    rows = report()
    for row in rows:
        if args.all or row.stale:
            print(row.line())
    print(f"{sum(r.stale for r in rows)} of {len(rows)} results files are stale")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
