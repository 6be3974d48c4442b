"""The planner: reflectance-only plans do no profile work, RGB grids keep their colour error,
profiles narrower than a pixel are skipped only when they are, derivatives are right."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skinfit
from skinfit import planning as planner
from skinfit.colorimetry import delta_e2000, linear_srgb_to_lab

from ..conftest import DJ2006

WAVELENGTHS = tuple(np.arange(400.0, 701.0, 10.0))


def _largest_intermediate(jaxpr) -> int:
    """Elements of the largest value any equation of ``jaxpr`` (and its sub-programs) produces."""
    largest = 0
    for eqn in jaxpr.eqns:
        for var in eqn.outvars:
            largest = max(largest, int(np.prod(getattr(var.aval, "shape", ()))))
        for param in eqn.params.values():
            inner = getattr(param, "jaxpr", None)
            if inner is not None:
                largest = max(largest, _largest_intermediate(getattr(inner, "jaxpr", inner)))
    return largest


def test_reflectance_only_plan_has_no_profile_work():
    the_plan = planner.plan(wavelengths_nm=WAVELENGTHS)
    assert not the_plan.computes_profiles and the_plan.radii_mm is None
    assert "profiles: not requested" in the_plan.describe()
    params = skinfit.SkinParams(np.array([0.02, 0.2]), 0.7, np.array([0.01, 0.05]))
    scale = jnp.asarray(1.0)
    # The compiled program never holds more than one value per (parameter set, wavelength) on DJ2006's
    # closed form, and 4^3 tricubic coefficients per value on the tabulated transport of the default
    # model: no frequency axis, no radii, no Hankel kernel. With profiles it does.
    program = planner._program(the_plan)
    values = 2 * len(WAVELENGTHS)
    assert _largest_intermediate(jax.make_jaxpr(program)(params, DJ2006, scale).jaxpr) <= values
    assert _largest_intermediate(jax.make_jaxpr(program)(params, skinfit.SkinModel.default(), scale).jaxpr) <= 4**3 * values
    with_profiles = planner.plan(wavelengths_nm=WAVELENGTHS, profiles=True, profile_radii=8)
    program = planner._program(with_profiles)
    assert _largest_intermediate(jax.make_jaxpr(program)(params, DJ2006, scale).jaxpr) > 100 * values

    result = the_plan.evaluate(params)
    np.testing.assert_allclose(result.reflectance, skinfit.diffuse_reflectance(params, WAVELENGTHS), rtol=1e-14)
    assert result.profiles is None and result.rgb is None and result.derivatives is None


def test_rgb_plan_keeps_its_colour_error_on_parameters_it_was_not_chosen_on():
    tolerance = 0.1
    the_plan = planner.plan(rgb=True, colour_tolerance=tolerance)
    assert len(the_plan.colour_wavelengths_nm) < len(np.arange(380.0, 781.0, 5.0))
    rng = np.random.default_rng(5)
    params = skinfit.SkinParams(10 ** rng.uniform(-3, np.log10(0.5), 64), rng.uniform(0, 1, 64), 10 ** rng.uniform(-3, np.log10(0.3), 64))
    fine = np.arange(360.0, 831.0, 1.0)
    reference = skinfit.colorimetry.spectrum_to_linear_srgb(skinfit.diffuse_reflectance(params, fine), fine)
    planned = planner.evaluate(the_plan, params).rgb
    error = np.asarray(delta_e2000(linear_srgb_to_lab(reference), linear_srgb_to_lab(planned)))
    assert error.max() <= tolerance


@pytest.mark.slow
@pytest.mark.parametrize(("model_name", "footprint"), [("dj2006", 4.0), ("calibrated", 10.0)])
def test_a_profile_inside_one_pixel_is_skipped_and_really_is_inside(model_name, footprint):
    """A distant face, a few pixels across (the calibrated model's dark skin returns more light from
    far away than DJ2006's, so its profile fits inside a larger pixel only)."""
    params = skinfit.preset("dark")
    model = skinfit.SkinModel.named(model_name)
    skipped = planner.plan(rgb=True, profiles=True, pixel_footprint_mm=footprint, params=params, model=model)
    assert not skipped.computes_profiles and "not needed" in skipped.describe()
    # independent check: integrate the profile itself beyond half the footprint
    lam = np.asarray(skipped.model_wavelengths_nm)
    radii = np.geomspace(footprint / 2, 200.0, 4000)
    prof = np.asarray(skinfit.profile(params, lam, radii, entry_fresnel=True, model=model))
    outside = np.trapezoid(2 * np.pi * radii * prof, radii, axis=-1)
    total = np.asarray(skinfit.diffuse_reflectance(params, lam, model=model))
    assert np.all(outside <= skipped.request.energy_tolerance * total)

    kept = planner.plan(rgb=True, profiles=True, pixel_footprint_mm=0.2, params=skinfit.preset("light"))
    assert kept.computes_profiles and kept.radii_mm[0] == pytest.approx(0.1)


def test_profiles_and_derivatives_of_a_full_plan():
    params = skinfit.SkinParams(np.array([0.02, 0.2]), 0.7, np.array([0.01, 0.05]))
    the_plan = planner.plan(wavelengths_nm=WAVELENGTHS, rgb=True, profiles=True, derivatives=True, profile_radii=16)
    result = planner.evaluate(the_plan, params)
    expected = skinfit.profile(params, WAVELENGTHS, result.radii_mm, entry_fresnel=True)
    np.testing.assert_allclose(result.profiles, expected, rtol=1e-12, atol=1e-15 * float(np.max(expected)))
    assert result.rgb_profiles.shape == (2, 3, 16)
    h = 1e-6
    for name in planner.DERIVATIVE_NAMES:
        up = skinfit.SkinParams(**{f: np.asarray(getattr(params, f)) + (h if f == name else 0.0) for f in ("melanin", "melanin_blend", "haemoglobin")})
        down = skinfit.SkinParams(**{f: np.asarray(getattr(params, f)) - (h if f == name else 0.0) for f in ("melanin", "melanin_blend", "haemoglobin")})
        for output in ("reflectance", "rgb"):
            fd = (getattr(planner.evaluate(the_plan, up), output) - getattr(planner.evaluate(the_plan, down), output)) / (2 * h)
            np.testing.assert_allclose(result.derivatives[name][output], fd, rtol=1e-6, atol=1e-9)


def test_bad_requests_are_clear_errors():
    with pytest.raises(skinfit.SkinfitInputError, match="wavelengths_nm .* or rgb"):
        planner.Request()
    with pytest.raises(skinfit.SkinfitInputError, match="within 250"):
        planner.Request(wavelengths_nm=(200.0, 300.0))
    with pytest.raises(skinfit.SkinfitInputError, match="pixel_footprint_mm"):
        planner.Request(rgb=True, pixel_footprint_mm=-1.0)
