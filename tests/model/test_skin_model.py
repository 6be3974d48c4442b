"""The model object: DJ2006 constants, tracing without recompilation, files, optional chromophores."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skinfit
from skinfit import SkinfitInputError, SkinModel
from skinfit import model as chrom
from skinfit.model import ScatteringLaw, skin_reflectance

from ..conftest import DJ2006

WL = np.arange(400.0, 701.0, 20.0)


def test_dj2006_layers_match_the_published_coefficients(light):
    """model notes 5.4: light skin at 550 nm, sigma_a / sigma_s' of both layers."""
    epidermis, dermis = DJ2006.layers(light, np.array([550.0]))
    assert float(epidermis.absorption[0]) == pytest.approx(0.2606, abs=1e-4)
    assert float(epidermis.reduced_scattering[0]) == pytest.approx(6.082, abs=1e-3)
    assert float(dermis.absorption[0]) == pytest.approx(0.1679, abs=1e-4)
    assert float(dermis.reduced_scattering[0]) == pytest.approx(3.041, abs=1e-3)
    assert np.all(np.asarray(epidermis.thickness) == 0.25) and DJ2006.name == "dj2006"
    # the DJ2006 scattering law, 14.74 lambda^-0.22 + 2.2e11 lambda^-4, written at 500 nm
    lam = np.array([400.0, 777.0])
    np.testing.assert_allclose(DJ2006.epidermis_scattering(lam), 14.74 * lam**-0.22 + 2.2e11 * lam**-4, rtol=1e-13)


def test_changing_a_constant_inside_jit_does_not_retrace(light):
    traces = []

    @jax.jit
    def reflectance(model):
        traces.append(1)
        return skin_reflectance(light, jnp.asarray(WL), model)

    base = reflectance(DJ2006)
    variants = [
        DJ2006.replace(epidermis_thickness_mm=0.06),
        DJ2006.replace(blood_oxygenation=0.9),
        DJ2006.replace(epidermis_scattering=ScatteringLaw(20.0, 1.0, 0.0)),
        DJ2006.replace(vessel_radius_mm=0.005, epidermal_blood=0.2, carotene_umol_per_l=10.0, baseline_scale=1.5),
    ]
    for model in variants:
        assert not np.allclose(reflectance(model), base)
    assert len(traces) == 1


def test_a_fit_with_other_constants_does_not_recompile(monkeypatch):
    """fit_spectra traces the model (SkinModel.layers) only while compiling: a second fit with other
    constants and other fixed values, whose spectra it fits exactly, traces nothing."""
    calls = []
    layers = SkinModel.layers
    monkeypatch.setattr(SkinModel, "layers", lambda self, *a, **k: calls.append(1) or layers(self, *a, **k))
    params = skinfit.SkinParams(np.array([0.02, 0.2]), np.array([0.6, 0.3]), np.array([0.01, 0.05]))

    def fit(model, thickness):
        spectra = np.asarray(skinfit.diffuse_reflectance(params, WL, model=model, epidermis_thickness_mm=thickness))
        return skinfit.fit_spectra(WL, spectra, model=model, fixed={"epidermis_thickness_mm": thickness}, free=skinfit.fit.CHROMOPHORES,
                                   progress=False)

    first = fit(DJ2006, 0.2)
    compiled = len(calls)
    second = fit(DJ2006.replace(blood_oxygenation=0.9, dermis_scattering=ScatteringLaw(5.0, 1.2, 0.5)), 0.1)
    assert compiled > 0 and len(calls) == compiled
    for result in (first, second):
        np.testing.assert_allclose(result.parameters["melanin"], params.melanin, rtol=1e-6)


def test_a_repeated_fit_of_measured_like_spectra_compiles_nothing(monkeypatch):
    """Noisy spectra take every solver stage (gathered Gauss-Newton, the bounded polish); a second
    identical call must reuse every compiled program."""
    rng = np.random.default_rng(4)
    params = skinfit.SkinParams(rng.uniform(0.01, 0.3, 16), rng.uniform(0.0, 1.0, 16), rng.uniform(0.005, 0.08, 16))
    spectra = np.asarray(skinfit.diffuse_reflectance(params, WL, model=DJ2006)) * (1 + 0.01 * rng.standard_normal((16, WL.size)))
    skinfit.fit_spectra(WL, spectra, model=DJ2006, progress=False)
    calls = []
    layers = SkinModel.layers
    monkeypatch.setattr(SkinModel, "layers", lambda self, *a, **k: calls.append(1) or layers(self, *a, **k))
    skinfit.fit_spectra(WL, spectra, model=DJ2006, progress=False)
    assert calls == []


def test_gradients_and_vmap_go_through_the_constants(light):
    def total(thickness):
        return jnp.sum(skinfit.diffuse_reflectance(light, WL, model=DJ2006.replace(epidermis_thickness_mm=thickness)))

    g = jax.grad(total)(0.2)
    fd = (total(0.2 + 1e-6) - total(0.2 - 1e-6)) / 2e-6
    assert float(g) == pytest.approx(float(fd), rel=1e-5)
    many = jax.vmap(lambda d: skinfit.diffuse_reflectance(light, WL, model=DJ2006.replace(epidermis_thickness_mm=d)))(jnp.array([0.1, 0.25]))
    np.testing.assert_allclose(many[1], skinfit.diffuse_reflectance(light, WL, model=DJ2006), rtol=1e-13)
    assert np.all(np.isfinite(jax.grad(lambda r: jnp.sum(skin_reflectance(light, jnp.asarray(WL), DJ2006.replace(vessel_radius_mm=r))))(0.0)))


def test_optional_chromophores_default_to_dj2006_and_act_where_they_should(light):
    base = np.asarray(skinfit.diffuse_reflectance(light, WL, model=DJ2006))
    carotene = np.asarray(skinfit.diffuse_reflectance(light, WL, model=DJ2006.replace(carotene_umol_per_l=50.0)))
    blue, red = WL < 500, WL > 560
    assert np.all(carotene[blue] < base[blue]) and np.allclose(carotene[red], base[red], rtol=1e-12)
    packed = np.asarray(skinfit.diffuse_reflectance(light, WL, model=DJ2006.replace(vessel_radius_mm=0.01)))
    assert np.all(packed >= base)  # packed blood absorbs less
    epidermal = np.asarray(skinfit.diffuse_reflectance(light, WL, model=DJ2006.replace(epidermal_blood=0.5)))
    assert np.all(epidermal < base)
    # beta-carotene: Prahl's table peaks at 451 nm with 139,500 cm^-1/M
    assert float(chrom.carotene_absorption(451.0)) == pytest.approx(np.log(10) * 139500 / 10 * 1e-6, rel=2e-3)
    assert float(chrom.packaging_factor(jnp.asarray(40.0), 0.005)) == pytest.approx((1 - np.exp(-0.4)) / 0.4, rel=1e-12)


def test_model_files_round_trip(tmp_path):
    model = DJ2006.replace(blood_oxygenation=0.9, vessel_radius_mm=0.004, name="mine")
    path = tmp_path / "model.json"
    model.save(path, note="test")
    loaded = SkinModel.from_file(path)
    assert loaded.name == "mine"
    np.testing.assert_array_equal(skinfit.diffuse_reflectance(skinfit.preset("medium"), WL, model=loaded),
                                  skinfit.diffuse_reflectance(skinfit.preset("medium"), WL, model=model))
    assert SkinModel.named(str(path)).name == "mine" and SkinModel.named("dj2006").name == "dj2006"


@pytest.mark.parametrize(
    "make, word",
    [
        (lambda: DJ2006.replace(blood_oxygenation=1.5).check(), "blood_oxygenation"),
        (lambda: DJ2006.replace(thickness=1.0), "unknown SkinModel field"),
        (lambda: DJ2006.replace(method=skinfit.Transport(0.8, 1.33)), "ior"),
        (lambda: SkinModel.named("nonsense"), "unknown model"),
        (lambda: skinfit.diffuse_reflectance(skinfit.preset("light"), WL, model="dj2006"), "SkinModel"),
    ],
)
def test_bad_models_are_clear_errors(make, word):
    with pytest.raises(SkinfitInputError, match=word):
        make()


def test_the_calibrated_model_is_the_default_and_round_trips():
    model = SkinModel.default()
    assert model.name == SkinModel.calibrated().name != "dj2006" and model.prior is not None
    assert isinstance(model.method, skinfit.Transport) and model.method.table is not None
    params = skinfit.SkinParams(np.array([0.03, 0.3]), np.array([0.5, 0.2]), np.array([0.02, 0.06]))
    spectra = np.asarray(skinfit.diffuse_reflectance(params, WL))
    fit = skinfit.fit_spectra(WL, spectra, prior=False, progress=False)  # maximum likelihood: exact
    for name in ("melanin", "melanin_blend", "haemoglobin"):
        np.testing.assert_allclose(fit.parameters[name], getattr(params, name), rtol=1e-5, atol=1e-7)
    # the default MAP fit under the population prior pulls well-determined melanin only slightly
    fit = skinfit.fit_spectra(WL, spectra, progress=False)
    assert np.all(fit.status == skinfit.FitStatus.SUCCESS) and np.max(fit.delta_e2000) < 0.1
    np.testing.assert_allclose(fit.parameters["melanin"], params.melanin, rtol=0.01)
    # the tabulated transport follows the direct adding-doubling for this model
    direct = skinfit.diffuse_reflectance(params, WL, method="transport-direct")
    np.testing.assert_allclose(spectra, direct, rtol=1e-4)
