"""The benchmark command runs and writes what it promises; the Pareto front is what it says."""

import csv

import pytest

from benchmarks import __main__ as bench
from benchmarks.pareto import Point, pareto_front


def point(time_s, error, name="x"):
    return Point("colour", name, time_s, 0.0, error, "dE")


def test_pareto_front_keeps_trade_offs_and_ignores_noise():
    fast, accurate, worse = point(1.0, 0.1, "fast"), point(10.0, 0.001, "accurate"), point(5.0, 0.5, "worse")
    assert {p.setting for p in pareto_front([fast, accurate, worse])} == {"fast", "accurate"}
    # 5 % slower at the same error is timing noise, not a loss
    assert len(pareto_front([point(1.0, 0.1), point(1.05, 0.1)])) == 2
    # below the colour floor (1e-3 CIEDE2000) errors are equal: time decides
    assert [p.setting for p in pareto_front([point(1.0, 1e-4, "a"), point(2.0, 1e-6, "b")])] == ["a"]


def test_benchmark_command_writes_csv_plots_and_summary(tmp_path):
    assert bench.main(["--only", "planner", "--stress-points", "0", "--repeats", "1", "--out", str(tmp_path)]) == 0
    rows = list(csv.DictReader(open(tmp_path / "points.csv")))
    assert {r["setting"] for r in rows} == {"reflectance + profiles (256 radii)", "reflectance only"}
    assert all(float(r["time_s"]) > 0 for r in rows)
    assert (tmp_path / "pareto_planner.png").stat().st_size > 10_000
    summary = (tmp_path / "summary.md").read_text()
    assert "Reflectance only costs 1/" in summary


@pytest.mark.slow
def test_transport_benchmark_writes_its_results(tmp_path):
    """benchmarks.transport_fit on two NIST subjects: both methods fit, transport lower in residual."""
    import json

    from benchmarks import transport_fit

    assert transport_fit.main(["--n", "2", "--batch", "4", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "transport_fit.json").read_text())
    assert result["cost"]["transport_over_diffusion"] > 1.0
    assert result["nist"]["diffusion"]["success"] == result["nist"]["transport"]["success"] == 2
    assert result["nist"]["rms_transport_below_diffusion"] == 2
    assert len((tmp_path / "transport_fit_nist.csv").read_text().splitlines()) == 3
    assert (tmp_path / "transport_fit_nist.png").stat().st_size > 0
