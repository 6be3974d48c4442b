"""The bounded polish that finishes spectral fits: range positions, the exact curvature term, the
projected step onto a bound, and convergence of both stages from perturbed starts."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skinfit
from skinfit.fit import _spectra
from skinfit.fit._transport_polish import BoundedPolish

WAVELENGTHS = tuple(np.arange(400.0, 701.0, 20.0).tolist())
EXTENDED = ("melanin", "melanin_blend", "haemoglobin", "blood_oxygenation", "epidermis_thickness_mm", "scattering_scale",
            "specular_offset")


def polish(free, **options):
    return BoundedPolish(free, WAVELENGTHS, (1.0,) * len(WAVELENGTHS), 1e-7, 1e-6, **options)


@pytest.mark.parametrize("logarithmic", [False, True])
def test_positions_round_trip_with_their_slope(logarithmic):
    p = polish(EXTENDED, logarithmic=logarithmic)
    low, high = np.asarray(p.low), np.asarray(p.low + p.span)
    theta = np.stack([low, high, low + 0.37 * (high - low), low + 1e-5 * (high - low)])
    x = p.position(theta)
    assert np.all((x >= 0.0) & (x <= 1.0)) and np.all(x[0] == 0.0) and np.all(x[1] == 1.0)
    np.testing.assert_allclose(p.physical(x), theta, rtol=1e-12, atol=1e-15)
    slope = jax.vmap(jax.jacfwd(p.physical))(jnp.asarray(x))
    np.testing.assert_allclose(jnp.diagonal(slope, axis1=1, axis2=2), p.slope(jnp.asarray(x)), rtol=1e-12)
    # logarithmic positions: the thickness (0.01-1 mm) doubles over the same step of x wherever it is
    i = EXTENDED.index("epidermis_thickness_mm")
    rows = np.repeat(theta[2:3], 3, axis=0)
    rows[:, i] = [0.02, 0.04, 0.08]
    steps = np.diff(p.position(rows)[:, i])
    if logarithmic:
        np.testing.assert_allclose(steps[0], steps[1], rtol=1e-12)
    else:
        assert steps[1] == pytest.approx(2.0 * steps[0], rel=1e-12)


def test_exact_curvature_is_the_second_order_part_of_the_hessian():
    """S = sum_i r_i Hessian(r_i): the Hessian of 0.5 |r|^2 less J^T J, at a point away from the optimum."""
    skin = skinfit.SkinModel.dj2006()
    measurement = _spectra.measurement_model(skin, EXTENDED, None, None)
    p = polish(measurement.free, exact_curvature=True)
    target = jnp.asarray(np.linspace(0.25, 0.55, len(WAVELENGTHS)))
    x = jnp.asarray([0.3, 0.4, 0.3, 0.7, 0.35, 0.5, 0.1])
    r, jacobian = p._linearise(measurement, x, target)
    curvature = p._exact_curvature(measurement, x, target, r)
    cost = lambda z: 0.5 * jnp.sum(p._linearise(measurement, z, target)[0] ** 2)  # noqa: E731
    np.testing.assert_allclose(curvature, jax.hessian(cost)(x) - jacobian.T @ jacobian, rtol=1e-7, atol=1e-10)
    assert np.max(np.abs(curvature)) > 1e-3 * np.max(np.abs(jacobian.T @ jacobian))  # not a vanishing term here


def test_a_variable_pushed_onto_its_bound_is_held_there():
    p = polish(("melanin", "melanin_blend"))
    # the cost falls as x0 falls: 0.5 |(x0 + 1, x1 - 0.5)|^2; x0 starts within the active band of 0
    x = jnp.asarray([5e-5, 0.2])
    residual = jnp.asarray([x[0] + 1.0, x[1] - 0.5])
    state = _state(x, residual, jnp.eye(2))
    step, predicted = p._model_step(state, 0.0)
    np.testing.assert_allclose(step, [-5e-5, 0.3], atol=1e-15)  # onto the bound, and the free one's Newton step
    assert predicted > 0.0


def _state(x, residual, jacobian):
    from skinfit.fit._lockstep import LockstepState
    from skinfit.fit._transport_polish import _Linearisation

    carry = _Linearisation(residual, jacobian, jnp.zeros((x.size, x.size)), jnp.asarray(1e-3), jnp.asarray(jnp.inf))
    return LockstepState(x, jnp.sum(residual**2), carry)


@pytest.mark.parametrize("exact", [False, True])
def test_each_stage_converges_into_the_basin_of_the_truth(exact):
    """Noisy model spectra (1 %), starts 0.05 of each range from the truth: the secant stage (linear
    positions) and the exact stage (logarithmic) converge, each to a cost no higher than the truth's.
    (Not necessarily to the same point: with noise the fit has nearby local minima, seen 2.5 % apart
    in cost between the two stages from one start.)"""
    skin = skinfit.SkinModel.dj2006()
    rng = np.random.default_rng(7)
    truth = np.column_stack([rng.uniform(0.02, 0.3, 4), rng.uniform(0.2, 0.8, 4), rng.uniform(0.01, 0.08, 4)])
    lam = np.asarray(WAVELENGTHS)
    clean = np.asarray(skinfit.diffuse_reflectance(skinfit.SkinParams(*truth.T), lam, model=skin))
    target = clean * (1.0 + 0.01 * rng.standard_normal(clean.shape))
    measurement = _spectra.measurement_model(skin, None, None, None)
    cost = jax.jit(jax.vmap(lambda th, t: jnp.sum(measurement.residual_of_free(th, t, lam, jnp.ones(lam.size)) ** 2)))
    start = np.clip(truth + 0.05 * rng.choice([-1.0, 1.0], truth.shape), 0.0, 1.0)
    p = polish(measurement.free, exact_curvature=exact, logarithmic=exact)
    theta, steps, done = p.run(measurement, start, target, 60, 4, False)
    assert np.all(done) and np.all(steps <= 61)
    reached, at_truth = np.asarray(cost(theta, target)), np.asarray(cost(truth, target))
    assert np.all(reached <= at_truth)
