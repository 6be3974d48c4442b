"""The colour spline against the exact model, and the inverse table's warm starts."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from skinfit.colorimetry import chromaticity, colour_table, model_rgb, spline_rgb

from ..conftest import DJ2006


@pytest.fixture(scope="module")
def table():
    return colour_table(0.7)


@pytest.fixture(scope="module")
def random_roots():
    return np.random.default_rng(0).random((4000, 2))


def exact(roots, table):
    return model_rgb(jnp.asarray(roots), *table.model_arguments())


def test_spline_matches_the_model_between_nodes(table, random_roots):
    value, _, _ = spline_rgb(jnp.asarray(table.coefficients), jnp.asarray(random_roots))
    expected = np.asarray(exact(random_roots, table))
    # measured: max 2.8e-7, median 1.1e-10 (fourth order: 4.1e-6 at 65 nodes)
    assert np.max(np.abs(value - expected)) < 1e-6
    assert np.median(np.abs(value - expected)) < 1e-9


def test_spline_is_exact_at_nodes_and_edges(table):
    nodes = np.array([[0.0, 0.0], [1.0, 1.0], [0.5, 1.0], [1.0, 0.25], [3 / 128, 5 / 128]])
    value, _, _ = spline_rgb(jnp.asarray(table.coefficients), jnp.asarray(nodes))
    np.testing.assert_allclose(value, exact(nodes, table), atol=1e-13)


def test_spline_derivatives_match_autodiff_of_the_model(table, random_roots):
    roots = random_roots[:200]
    _, d_u, d_v = spline_rgb(jnp.asarray(table.coefficients), jnp.asarray(roots))
    jacobian = jax.vmap(jax.jacfwd(lambda r: exact(r[None], table)[0]))(jnp.asarray(roots))  # (n, 3, 2)
    scale = np.max(np.abs(jacobian))
    np.testing.assert_allclose(d_u, jacobian[..., 0], atol=1e-4 * scale)
    np.testing.assert_allclose(d_v, jacobian[..., 1], atol=1e-4 * scale)


def test_a_warm_start_has_the_pixel_chromaticity(table, random_roots):
    colours = np.asarray(exact(random_roots, table)) * 0.6  # shading does not move chromaticity
    starts = table.warm_starts(colours)
    assert starts.shape == (len(colours), 2, 2)
    start_colour, _, _ = spline_rgb(jnp.asarray(table.coefficients), jnp.asarray(starts[:, 0]))
    distance = np.linalg.norm(chromaticity(np.asarray(start_colour)) - chromaticity(colours), axis=-1)
    assert np.percentile(distance, 99) < 1e-3  # the whole table spans ~0.1 in chromaticity


def test_table_rejects_a_blend_outside_the_unit_interval():
    from skinfit import SkinfitInputError

    with pytest.raises(SkinfitInputError, match="melanin_blend"):
        colour_table(1.5)


@pytest.mark.slow
def test_transport_table_interpolates_the_transport_model():
    """method="transport-direct": node values from adding-doubling, derivatives from the interpolating
    spline; on a coarse 17 x 17 table (the image-fit test's) the spline follows exact transport in
    linear sRGB (measured: max 1.4e-3 near the box edge, where the not-a-knot end conditions are
    weakest; 2.0e-4 on the default 33 x 33), and differs clearly from diffusion's colour."""
    table = colour_table(0.7, nodes=17, inverse_cells=64, method="transport-direct", model=DJ2006)
    roots = np.random.default_rng(2).uniform(0.0, 1.0, (64, 2))
    exact = np.asarray(model_rgb(jnp.asarray(roots), *table.model_arguments()))
    spline = np.asarray(spline_rgb(jnp.asarray(table.coefficients), jnp.asarray(roots))[0])
    assert np.max(np.abs(spline - exact)) < 3e-3
    assert np.median(np.abs(spline - exact)) < 2e-5
    diffusion = np.asarray(model_rgb(jnp.asarray(roots), *table.model_arguments()[:-1], DJ2006))
    assert np.median(np.abs(diffusion - exact) / exact) > 0.1
