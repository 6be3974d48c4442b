"""Saved benchmark results: each is listed with its script and code, and says when and where it was made.

Whether a file predates its code is a report a maintainer asks for (``python -m benchmarks.stale``),
not a warning in every test run; here the report's mechanism is checked on the repository's history.
"""

import json
import subprocess

import pytest

from benchmarks.stale import DEPENDS_ON, RESULTS, ROOT, _git, changed_since, report


def test_every_results_file_is_listed_and_says_when_and_where_it_was_made():
    saved = {p.name for p in RESULTS.glob("*.json")}
    assert saved == set(DEPENDS_ON), f"list new results files in benchmarks/stale.py: {sorted(saved ^ set(DEPENDS_ON))}"
    for name, (script, paths) in DEPENDS_ON.items():
        record = json.loads((RESULTS / name).read_text())
        assert record.get("date") and record.get("machine"), name
        assert (ROOT / script).is_file(), script
        assert all((ROOT / path).exists() for path in paths), (name, paths)


@pytest.fixture(scope="module")
def first_commit():
    try:
        return _git("rev-list", "--max-parents=0", "HEAD").splitlines()[0]
    except (OSError, subprocess.CalledProcessError, IndexError):
        pytest.skip("not a git checkout")


def test_the_staleness_check_sees_a_change(first_commit):
    # the mechanism can fail: from the repository's first commit, the model has changed
    assert changed_since(first_commit, ["skinfit"])


def test_a_docstring_edit_does_not_make_a_result_stale():
    # HEAD against itself: no change; and the comparison ignores docstrings (same syntax tree)
    from benchmarks.stale import _code
    assert changed_since("HEAD", ["skinfit"]) == []
    assert _code('def f():\n    """one"""\n    return 1\n') == _code('def f():\n    """two"""\n    return 1  # why\n')
    assert _code("def f():\n    return 1\n") != _code("def f():\n    return 2\n")


def test_the_report_has_a_line_for_every_results_file(first_commit):
    rows = report()
    assert [r.name for r in rows] == list(DEPENDS_ON)
    for row in rows:
        assert row.line().startswith(row.name)
        assert row.stale == (row.commit is None or not row.in_history or bool(row.changed))
