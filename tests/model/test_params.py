import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skinfit
from skinfit import SkinfitInputError, SkinParams


def test_fields_broadcast_and_shape():
    p = SkinParams(melanin=np.linspace(0.01, 0.4, 4)[:, None], melanin_blend=0.7, haemoglobin=np.array([0.01, 0.05, 0.1]))
    assert p.shape == (4, 3)
    r = skinfit.diffuse_reflectance(p, [450.0, 550.0])
    assert r.shape == (4, 3, 2)


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(melanin=1.5, melanin_blend=0.5, haemoglobin=0.01), "melanin"),
        (dict(melanin=0.1, melanin_blend=-0.1, haemoglobin=0.01), "melanin_blend"),
        (dict(melanin=0.1, melanin_blend=0.5, haemoglobin=np.nan), "haemoglobin"),
        (dict(melanin=0.1, melanin_blend=0.5, haemoglobin=0.01, oil=2.0), "oil"),
        (dict(melanin="a lot", melanin_blend=0.5, haemoglobin=0.01), "melanin"),
    ],
)
def test_out_of_range_values_raise_clear_errors(kwargs, word):
    with pytest.raises(SkinfitInputError, match=word):
        SkinParams(**kwargs)


def test_non_broadcasting_fields_raise():
    with pytest.raises(SkinfitInputError, match="broadcast"):
        SkinParams(melanin=np.ones(3) * 0.1, melanin_blend=np.ones(4) * 0.5, haemoglobin=0.01)


def test_pytree_under_jit_vmap_grad():
    wl = jnp.array([450.0, 550.0, 650.0])
    batch = SkinParams(melanin=jnp.array([0.01, 0.1]), melanin_blend=jnp.array([0.5, 0.7]), haemoglobin=jnp.array([0.01, 0.02]))
    direct = skinfit.diffuse_reflectance(batch, wl)
    mapped = jax.vmap(lambda p: skinfit.diffuse_reflectance(p, wl))(batch)
    jitted = jax.jit(lambda p: skinfit.diffuse_reflectance(p, wl))(batch)
    np.testing.assert_allclose(mapped, direct, rtol=1e-13)
    np.testing.assert_allclose(jitted, direct, rtol=1e-13)
    grads = jax.grad(lambda p: skinfit.diffuse_reflectance(p, wl).sum())(skinfit.preset("light"))
    assert isinstance(grads, SkinParams)
    assert float(grads.melanin) < 0 and float(grads.haemoglobin) < 0


def test_presets_and_their_sources():
    assert skinfit.PRESET_NAMES == ("light", "medium", "dark")
    light = skinfit.preset("light")
    assert (float(light.melanin), float(light.melanin_blend), float(light.haemoglobin)) == (0.005, 0.7, 0.005)
    for name in skinfit.PRESET_NAMES:
        assert "damlaren" in skinfit.model.preset_source(name)
    with pytest.raises(SkinfitInputError, match="unknown preset"):
        skinfit.preset("pale")
