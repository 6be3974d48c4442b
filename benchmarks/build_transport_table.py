"""Build the shipped two-layer transport table and measure it against direct adding-doubling.

Run: python -m benchmarks.build_transport_table [--nodes 129 97 41] [--points 1000] [--no-build]

1. Build: ``skinfit.model.build_transport_table(0.8, 1.4, streams=16)`` on the default
   nodes, written to spectra/transport_table_g0.80_n1.400.npz (the package's shipped table);
   ``--no-build`` measures the file that is there.
2. Accuracy: the table's relative error at random points off the nodes, against
   ``stack_reflectance_transport`` of the two-layer stack:
   - uniform in (x1, x2, x3) = (log sigma_a1/sigma_s1', log sigma_s1' d, log sigma_a2/sigma_s2')
     over the box [1e-5, 1e2] x [1e-2, 1e2] x [1e-5, 1e2];
   - skin-like: sigma_s' 2-40 mm^-1, d 0.02-0.3 mm, sigma_a 0.01-200 mm^-1, log-uniform and
     independent per layer.
   Where the epidermis is saturated (30 decay lengths deep, ``saturation_thickness``), the
   table holds the value at the saturation thickness, since the direct solver drifts at optical
   depths of hundreds (1e-3 at ~400) and overflows beyond. Those uniform points are compared with
   the exact saturated limit, the epidermis alone as a semi-infinite layer (whose doubling starts
   thin); the raw comparison with the two-layer solver is reported where its optical depth is
   <= 200, and saturation itself is checked there (two-layer against semi-infinite epidermis).
3. Cost per 31-wavelength spectrum after compilation (median of repeats): the table's values, its
   values and gradient (reverse mode through all five inputs), and the direct solver.

Writes benchmarks/results/transport_table.json (with date, machine, git commit).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import skinfit  # noqa: F401 - float64
from benchmarks._record import git_commit
from benchmarks._timing import median_seconds
from skinfit import model
from skinfit.model import stack_reflectance_transport

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "spectra" / "transport_table_g0.80_n1.400.npz"
G, N, STREAMS = 0.8, 1.4, 16
#: Optical depth of the epidermis up to which the direct two-layer result is taken as exact.
DIRECT_DEPTH = 200.0
SKIN = {"reduced_scattering": (2.0, 40.0), "thickness": (0.02, 0.3), "absorption": (0.01, 200.0)}


def skin_like(rng, n: int) -> np.ndarray:
    """(n, 5) skin-like stacks (sigma_a1, sigma_s1', d, sigma_a2, sigma_s2'), log-uniform."""
    draw = lambda key: np.exp(rng.uniform(*np.log(SKIN[key]), n))  # noqa: E731
    return np.stack([draw("absorption"), draw("reduced_scattering"), draw("thickness"), draw("absorption"), draw("reduced_scattering")], -1)


def coordinates(stacks: np.ndarray) -> np.ndarray:
    sa1, ss1, d, sa2, ss2 = stacks.T
    return np.stack([np.log(sa1 / ss1), np.log(ss1 * d), np.log(sa2 / ss2)], -1)


def uniform(rng, n: int) -> np.ndarray:
    """(n, 3) points uniform in the log coordinates over the table's box."""
    lo = np.log([model.RATIO_RANGE[0], model.THICKNESS_RANGE[0], model.RATIO_RANGE[0]])
    hi = np.log([model.RATIO_RANGE[1], model.THICKNESS_RANGE[1], model.RATIO_RANGE[1]])
    return rng.uniform(lo, hi, (n, 3))


def table_at(table, x: np.ndarray) -> np.ndarray:
    """The table at coordinates (n, 3), through its public entry (sigma_s' = 1)."""
    r1, sd, r3 = np.exp(x).T
    return np.asarray(table.reflectance(r1, 1.0, sd, r3, 1.0))


def semi_infinite_epidermis(x1: np.ndarray) -> np.ndarray:
    """The saturated limit: the epidermis's material alone, semi-infinite."""
    x = np.stack([x1, np.zeros_like(x1), x1], -1)  # dermis = epidermis: the thickness drops out
    return model.node_reflectance(x, G, N, STREAMS, progress=False)


def summary(error: np.ndarray, x: np.ndarray) -> dict:
    error = np.abs(error)
    worst = np.argsort(error)[::-1][:5]
    return {
        "points": int(error.size),
        "median": float(np.median(error)),
        "p99": float(np.quantile(error, 0.99)),
        "max": float(error.max()),
        "worst_at_x1_x2_x3": [[round(float(v), 3) for v in x[i]] for i in worst],
        "worst_errors": [float(error[i]) for i in worst],
    }


def accuracy(table, points: int, seed: int = 7) -> dict:
    rng = np.random.default_rng(seed)
    result = {}
    # skin-like: every point within the direct solver's reach (optical depth <= 120)
    stacks = skin_like(rng, points)
    x = coordinates(stacks)
    direct = model.node_reflectance(x, G, N, STREAMS, progress=False)
    got = np.asarray(table.reflectance(*(stacks[:, i] for i in range(5))))
    result["skin_like"] = summary(got / direct - 1.0, x)

    x = uniform(rng, points)
    got = table_at(table, x)
    direct = model.node_reflectance(x, G, N, STREAMS, progress=False)
    depth = (np.exp(x[:, 0]) + 1.0 / (1.0 - G)) * np.exp(x[:, 1])
    saturated = x[:, 1] >= model.saturation_thickness(x[:, 0], G)
    limit = semi_infinite_epidermis(x[:, 0])
    reference = np.where(saturated, limit, direct)
    reach = depth <= DIRECT_DEPTH
    result["uniform"] = summary(got / reference - 1.0, x)
    result["uniform"]["saturated_points"] = int(saturated.sum())
    result["uniform_vs_two_layer_solver"] = summary((got / direct - 1.0)[reach], x[reach])
    result["uniform_vs_two_layer_solver"]["left_out_beyond_depth"] = DIRECT_DEPTH
    bad = ~np.isfinite(direct) | (np.abs(direct / limit - 1.0) > 1e-3)
    result["two_layer_solver_beyond_depth"] = {
        "points": int((~reach).sum()),
        "off_saturated_limit_by_over_1e-3_or_nan": int((bad & ~reach & saturated).sum()),
    }
    check = saturated & reach
    result["saturation_check"] = {
        "points": int(check.sum()),
        "max_two_layer_vs_semi_infinite_epidermis": float(np.max(np.abs(direct[check] / limit[check] - 1.0))) if check.any() else None,
    }
    return result


def cost(table, batch: int = 64, direct_batch: int = 8) -> dict:
    """Seconds per spectrum of 31 wavelengths (skin-like stacks per wavelength)."""
    rng = np.random.default_rng(3)
    stacks = skin_like(rng, batch * 31).reshape(batch, 31, 5)
    args = [jnp.asarray(stacks[..., i]) for i in range(5)]
    values = jax.jit(lambda t, *a: t.reflectance(*a))
    gradient = jax.jit(jax.value_and_grad(lambda a, t: jnp.sum(t.reflectance(*a))))

    def direct(sa1, ss1, d, sa2, ss2):
        one = lambda *s: stack_reflectance_transport(jnp.stack([s[0], s[3]]), jnp.stack([s[1], s[4]]), jnp.stack([s[2], 1.0]),  # noqa: E731
                                                     jnp.full(2, G), ior=N, ior_above=1.0, semi_infinite=True, streams=STREAMS)
        return jax.vmap(jax.vmap(one))(sa1, ss1, d, sa2, ss2)

    # a batch takes well under a millisecond: the median of many calls, or the shared machine's noise wins
    table_s = median_seconds(values, table, *args, repeats=201) / batch
    one_spectrum = median_seconds(values, table, *(a[0] for a in args), repeats=201)
    gradient_s = median_seconds(gradient, args, table, repeats=201) / batch
    direct_s = median_seconds(jax.jit(direct), *(a[:direct_batch] for a in args), repeats=3) / direct_batch
    return {
        "wavelengths": 31,
        "table_s_per_spectrum": table_s,
        "table_s_one_spectrum_call": one_spectrum,
        "table_value_and_grad_s_per_spectrum": gradient_s,
        "direct_s_per_spectrum": direct_s,
        "direct_over_table": direct_s / table_s,
        "batch_spectra": batch,
        "direct_batch_spectra": direct_batch,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--nodes", type=int, nargs=3, default=list(model.DEFAULT_NODES), help="nodes along x1, x2, x3")
    parser.add_argument("--points", type=int, default=1000, help="random points per accuracy set")
    parser.add_argument("--table", default=str(SHIPPED), help="where to write (or, with --no-build, read) the table")
    parser.add_argument("--no-build", action="store_true", help="measure the table file that is there")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)

    result = {
        "date": time.strftime("%Y-%m-%d"),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, {jax.devices()[0].device_kind}",
        "git_commit": git_commit(),
        "anisotropy": G, "ior": N, "streams": STREAMS,
    }
    if args.no_build:
        table = model.load_table(args.table)
        previous = Path(args.out) / "transport_table.json"
        if previous.is_file() and "build_s" in (earlier := json.loads(previous.read_text())):
            # keep the build time of the file measured, with where it was measured
            result["build_s"] = earlier["build_s"]
            result["build_note"] = earlier.get("build_note", f"build_s from the build at {earlier.get('git_commit', '?')[:10]} "
                                               f"({earlier.get('date', '?')}); this run measured that file (--no-build)")
    else:
        start = time.perf_counter()
        table = model.build_transport_table(G, N, streams=STREAMS, nodes=tuple(args.nodes))
        result["build_s"] = time.perf_counter() - start
        model.save_table(table, args.table)
    result["nodes"] = list(table.nodes)
    result["lower"], result["step"] = list(table.lower), list(table.step)
    result["file_bytes"] = Path(args.table).stat().st_size
    print(json.dumps({k: result[k] for k in ("nodes", "file_bytes", "build_s") if k in result}), flush=True)
    result["accuracy"] = accuracy(table, args.points)
    print(json.dumps(result["accuracy"], indent=1), flush=True)
    result["cost"] = cost(table)
    print(json.dumps(result["cost"], indent=1), flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "transport_table.json").write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    main()
