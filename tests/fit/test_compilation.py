"""Compile once per problem shape: fixed values and model constants are traced, not baked in.

Counted with JAX's own compilation events (``jax.monitoring``): every XLA backend compilation in the
process reports one.
"""

import jax
import numpy as np

import skinfit

_COMPILES: list[str] = []
_ACTIVE = [False]


def _listener(name, seconds, **kwargs):
    if _ACTIVE[0] and "backend_compile" in name:
        _COMPILES.append(name)


jax.monitoring.register_event_duration_secs_listener(_listener)


def _compilations(run) -> int:
    _COMPILES.clear()
    _ACTIVE[0] = True
    try:
        run()
    finally:
        _ACTIVE[0] = False
    return len(_COMPILES)


def test_a_new_fixed_value_or_model_constant_compiles_nothing():
    wl = np.arange(400.0, 701.0, 10.0)
    model = skinfit.SkinModel.dj2006()
    truth = skinfit.SkinParams(np.array([0.05, 0.2]), np.array([0.7, 0.5]), np.array([0.01, 0.03]))
    spectra = np.asarray(skinfit.diffuse_reflectance(truth, wl, model=model))
    free = ("melanin", "melanin_blend", "haemoglobin")

    def fit(oxygenation, thickness):
        return skinfit.fit_spectra(wl, spectra, model=model.replace(epidermis_thickness_mm=thickness), free=free,
                                   fixed={"blood_oxygenation": oxygenation}, progress=False)

    # warm up: the fit's programs, and the warm-start table's for a model not cached on disk
    assert _compilations(lambda: fit(0.75, 0.25)) > 0  # the counter sees compilations
    _compilations(lambda: fit(0.75, 0.3))
    assert _compilations(lambda: fit(0.6, 0.3)) == 0  # another fixed value
    assert _compilations(lambda: fit(0.6, 0.21)) == 0  # another model constant (and its new table)
    result = fit(0.75, 0.25)
    assert np.all(result.status == skinfit.FitStatus.SUCCESS)
    np.testing.assert_allclose(result.parameters["melanin"], [0.05, 0.2], rtol=1e-6)
