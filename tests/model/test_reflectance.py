import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skinfit
from skinfit import SkinfitInputError, SkinParams
from skinfit.model import Layer

from ..conftest import DJ2006

F0 = ((1.4 - 1) / (1.4 + 1)) ** 2  # 0.027778


def test_light_skin_fixture_times_entry_transmittance(light, light_fixture):
    got = skinfit.diffuse_reflectance(light, light_fixture["wavelengths_nm"], model=DJ2006)
    np.testing.assert_allclose(got, (1 - F0) * light_fixture["R12_directional"], atol=6e-5)
    sym = skinfit.diffuse_reflectance(light, light_fixture["wavelengths_nm"], adding="symmetric", model=DJ2006)
    np.testing.assert_allclose(sym, (1 - F0) * light_fixture["R12_symmetric"], atol=6e-5)


def test_layered_reflectance_of_the_skin_stack_is_diffuse_reflectance(light):
    wl = np.arange(400.0, 701.0, 25.0)
    layers = skinfit.model.skin_layers(light, wl, model=DJ2006)
    np.testing.assert_allclose(skinfit.layered_reflectance(layers), skinfit.diffuse_reflectance(light, wl, model=DJ2006), rtol=1e-14)
    # the default (calibrated, tabulated transport) model's stack through the direct adding-doubling
    model = skinfit.SkinModel.default()
    layers = [eqx.tree_at(lambda layer: layer.anisotropy, layer, jnp.full(jnp.shape(layer.absorption), model.method.anisotropy))
              for layer in skinfit.model.skin_layers(light, wl, model=model)]
    np.testing.assert_allclose(skinfit.layered_reflectance(layers, method="transport"), skinfit.diffuse_reflectance(light, wl), rtol=1e-4)


def test_user_layers_broadcast_and_validate():
    stack = [Layer(np.array([0.1, 0.5]), 5.0, 0.2), Layer(0.02, 2.0, float("inf"))]
    assert skinfit.layered_reflectance(stack).shape == (2,)
    with pytest.raises(SkinfitInputError, match="bottom layer"):
        skinfit.layered_reflectance([Layer(0.02, 2.0, float("inf")), Layer(0.1, 5.0, 0.2)])
    with pytest.raises(SkinfitInputError, match="thickness"):
        Layer(0.1, 5.0, -1.0)
    with pytest.raises(SkinfitInputError, match="absorption"):
        Layer(-0.1, 5.0, 1.0)
    with pytest.raises(SkinfitInputError, match="sequence of skinfit.model.Layer"):
        skinfit.layered_reflectance([])


def test_finite_bottom_layer_loses_light_downwards():
    thick = skinfit.layered_reflectance([Layer(0.01, 2.0, 50.0)])
    thin = skinfit.layered_reflectance([Layer(0.01, 2.0, 0.5)])
    semi = skinfit.layered_reflectance([Layer(0.01, 2.0, float("inf"))])
    assert float(thin) < float(thick) <= float(semi) + 1e-15


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(wavelengths_nm=[200.0, 500.0]), "wavelengths_nm"),
        (dict(wavelengths_nm=[[500.0]]), "1-D"),
        (dict(wavelengths_nm=[500.0], adding="sideways"), "adding"),
        (dict(wavelengths_nm=[500.0], blood_oxygenation=1.2), "blood_oxygenation"),
        (dict(wavelengths_nm=[500.0], epidermis_thickness_mm=0.0), "epidermis_thickness_mm"),
    ],
)
def test_bad_input_gives_clear_errors(light, kwargs, word):
    with pytest.raises(SkinfitInputError, match=word):
        skinfit.diffuse_reflectance(light, **kwargs)


def test_options_broadcast_with_parameters(light):
    thickness = jnp.array([0.1, 0.25, 0.5])
    r = skinfit.diffuse_reflectance(light, [550.0], epidermis_thickness_mm=thickness)
    assert r.shape == (3, 1)
    assert float(r[0, 0]) != float(r[2, 0])


def test_gradients_match_finite_differences():
    wl = jnp.array([420.0, 500.0, 560.0, 640.0])
    base = jnp.array([0.08, 0.6, 0.03, 0.7, 0.2])

    def model(x):
        p = SkinParams(melanin=x[0], melanin_blend=x[1], haemoglobin=x[2])
        return skinfit.diffuse_reflectance(p, wl, blood_oxygenation=x[3], epidermis_thickness_mm=x[4])

    jac = jax.jacfwd(model)(base)
    jac_rev = jax.jacrev(model)(base)
    h = 1e-6
    fd = jnp.stack([(model(base.at[i].add(h)) - model(base.at[i].add(-h))) / (2 * h) for i in range(5)], axis=-1)
    np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(jac_rev, jac, rtol=1e-12, atol=1e-14)  # entries ~1: round-off


def test_no_nan_or_inf_in_values_or_gradients_over_a_broad_sweep():
    rng = np.random.default_rng(0)
    n = 4000
    wl = jnp.asarray(rng.uniform(250.0, 1000.0, size=n))
    x = jnp.asarray(np.column_stack([rng.uniform(0, 1, n), rng.uniform(0, 1, n), rng.uniform(0, 1, n), rng.uniform(0, 1, n), 10 ** rng.uniform(-4, 1, n)]))
    # include the corners of the box exactly
    corners = jnp.array([[0, 0, 0, 0, 1e-4], [1, 1, 1, 1, 10.0], [0, 1, 0, 1, 1e-4], [1, 0, 1, 0, 10.0]], dtype=float)
    x = jnp.concatenate([x, corners])
    wl = jnp.concatenate([wl, jnp.array([250.0, 1000.0, 250.0, 1000.0])])

    def one(xi, lam):
        p = SkinParams(melanin=xi[0], melanin_blend=xi[1], haemoglobin=xi[2])
        return skinfit.diffuse_reflectance(p, lam[None], blood_oxygenation=xi[3], epidermis_thickness_mm=xi[4])[0]

    values = jax.vmap(one)(x, wl)
    grads = jax.vmap(jax.grad(one))(x, wl)
    assert int(jnp.sum(~jnp.isfinite(values))) == 0
    assert int(jnp.sum(~jnp.isfinite(grads))) == 0
    assert float(values.min()) >= 0.0 and float(values.max()) <= 1.0


def test_float32_inputs_compute_in_float32(light):
    p32 = jax.tree_util.tree_map(lambda a: a.astype(jnp.float32), light)
    wl = jnp.arange(400.0, 701.0, 10.0, dtype=jnp.float32)
    r32 = skinfit.diffuse_reflectance(p32, wl)
    assert r32.dtype == jnp.float32
    np.testing.assert_allclose(r32, skinfit.diffuse_reflectance(light, np.asarray(wl, float)), atol=2e-6)
    g = jax.grad(lambda p: skinfit.diffuse_reflectance(p, wl).sum())(p32)
    assert all(bool(jnp.isfinite(v)) for v in jax.tree_util.tree_leaves(g))
