"""The warm-start table: nearest-entry search and corrected candidates."""

import jax.numpy as jnp
import numpy as np

from skinfit.fit import CHROMOPHORES, build_fit_table, measurement_model
from skinfit.model import SkinModel

WAVELENGTHS = tuple(np.arange(400.0, 701.0, 20.0).tolist())
MODEL = measurement_model(SkinModel.dj2006(), CHROMOPHORES, None, None)


def small_table(weights=None):
    w = tuple(np.ones(len(WAVELENGTHS)).tolist()) if weights is None else weights
    return build_fit_table(MODEL, WAVELENGTHS, w, (8, 5, 8), (2, 2))


def test_groups_are_equal_size_and_cover_the_grid():
    table = small_table()
    groups, size, _ = table.grid_u.shape
    assert groups == 4
    # 8 x 5 x 8 entries; blend bands of 5 are uneven (3 + 2), so groups are padded with repeats
    unique = np.unique(np.asarray(table.grid_u).reshape(-1, 3), axis=0)
    assert len(unique) == 8 * 5 * 8


def test_nearest_entry_matches_brute_force_search():
    table = small_table()
    rng = np.random.default_rng(3)
    target = rng.uniform(0.05, 0.6, (300, len(WAVELENGTHS)))
    z = ((table.weights * target - table.mean) @ table.basis.T).astype(table.coords.dtype)
    nearest = np.asarray(table._nearest(jnp.asarray(z)))
    spectra = np.asarray(table.spectra)  # full-dimensional, float64 distances
    for g in range(spectra.shape[0]):
        distance = np.sum((target[:, None, :] - spectra[g][None]) ** 2, axis=-1)
        best = distance.min(axis=1)
        got = distance[np.arange(len(target)), nearest[:, g]]
        # the same entry up to float32 rounding and the basis truncation (1e-4 of the spread)
        assert np.all(got <= best + 1e-4 * (1.0 + best)), g


def test_a_table_spectrum_returns_its_own_entry_first():
    table = small_table()
    g, j = 2, 17
    target = table.spectra[g, j][None]
    start = np.asarray(table.candidates(target, 2))
    assert start.shape == (1, 2, 3)
    np.testing.assert_allclose(start[0, 0], np.asarray(table.grid_u[g, j]), atol=1e-8)
