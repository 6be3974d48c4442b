"""Bounded Levenberg-Marquardt with a curvature term: what finishes spectral fits.

It finishes the fits that the lock-step Gauss-Newton of ``_spectra`` leaves unconverged (most
measured spectra: large-residual problems), and direct transport fits, where a transport spectrum
costs 100 (GPU) to thousands (CPU) of diffusion spectra:

1. Each variable moves in its position x in [0, 1] of its range: linear, or logarithmic for the
   multiplicative ones (concentrations, thickness, scales; ``BoundedPolish.physical``). The box is
   handled by an active set (Bertsekas's projected Newton): a variable on or within 1e-4 of a bound
   whose gradient pushes outward moves onto the bound and is held there; the others take the damped
   step, clipped to the box. Optima on a bound (common for measured skin: no eumelanin) converge
   like interior ones.
2. The step solves (J^T J + S + damping D) step = -J^T r, with S the residuals' own curvature: a
   secant estimate (NL2SOL) by default, or exact (automatic differentiation, ~4 Jacobians) in the
   second stage of ``_spectra``, for fits in long curved valleys (the extended free sets).
3. It runs in lock-step rounds over the spectra still unconverged, gathered between rounds, each
   carrying its state, so a converged spectrum stops costing. One iteration is one forward-mode
   Jacobian.

A spectrum has converged when an accepted step moves no variable by more than ``step_tol`` of its
range, when it is first-order optimal (``_variables.stationarity``), or when the undamped model step
predicts a relative reduction of the cost below ``reduction_tol`` (NL2SOL's relative function
convergence).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._batching import map_batches, pad_size
from .._caching import eager_cache
from ..model import solve_dominant
from ._lockstep import LockstepState, evaluate_with_jacobian, placeholder
from ._variables import VARIABLES, stationarity

#: Lock-step iterations between two gatherings of the unconverged spectra.
ROUND_STEPS = 6
#: Batch of the rounds with fixed batches once few spectra are left (at most twice this many).
#: Measured in fits on a 2-core CPU (DJ2006, 31 wavelengths): a round costs 0.9 ms in a batch of
#: 16, 1.9 ms in one of 64 and 2.6 ms in one of 128 (the per-kernel cost of the loop's small-matrix
#: algebra dominates small batches), so large batches suit many spectra and small ones the last few.
STRAGGLER_BATCH = 16
_INITIAL_DAMPING = 1e-3
_ACTIVE_BAND = 1e-4  # range fraction from a bound within which a variable pushed outward is held on it
_CONVERGENCE_DAMPING = 1e-12  # keeps the model step's system regular in the convergence test


class _Linearisation(eqx.Module):
    """What the polish carries at its accepted point x (f,) (scaled to [0, 1]) beside the cost."""

    residual: jax.Array  # (m,) weighted residual at x
    jacobian: jax.Array  # (m, f) d residual / dx at x
    curvature: jax.Array  # (f, f) secant estimate of sum_i r_i Hessian(r_i) (the part Gauss-Newton drops)
    damping: jax.Array  # ()
    moved: jax.Array  # () largest |dx| of the last accepted step (inf before one)


class BoundedPolish:
    """Bounded Levenberg-Marquardt with a secant curvature term, for one measurement model,
    wavelength grid and weights.

    Measured skin spectra leave residuals far above their noise (the model cannot follow them
    exactly), and there Gauss-Newton's J^T J misses the residuals' own curvature: its steps
    zig-zag and converge linearly (measured on NIST spectra: 40 steps still 2 % from the optimum).
    As in NL2SOL (Dennis, Gay & Welsch 1981) the missing term is estimated from the change of the
    Jacobian along accepted steps (the structured secant update, with its sizing factor); the step
    solves (J^T J + S + damping D) step = -J^T r over the free variables and falls back to plain
    Gauss-Newton where J^T J + S is not a descent model. A Hessian by automatic differentiation
    would cost ~8 Jacobians of the transport spectrum per iteration; the secant update costs none.
    With ``exact_curvature`` S is computed exactly at every linearisation instead (about four
    Jacobians for three variables): for what the secant polish leaves, fits in long curved valleys
    whose curvature the secant update does not learn in 60 steps.

    ``logarithmic``: move the multiplicative variables in logarithmic range positions (see
    ``physical``). ``_spectra`` runs its secant stage in linear positions and its exact stage in
    logarithmic ones: measured on 1,000 ISSA face spectra (DJ2006, extended free set), logarithmic
    positions in the secant stage too ended 142 fits in local minima with a higher cost (up to
    12x) than the linear path reached (and 180 lower); in the exact stage alone they took the fits
    at MAX_STEPS from 43 (linear positions) to 3 (60 steps; 0 in 120).
    """

    def __init__(self, free: tuple, wavelengths: tuple, weights: tuple, step_tol: float, stationarity_tol: float,
                 exact_curvature: bool = False, reduction_tol: float = 1e-10, logarithmic: bool = True):
        self.reduction_tol = reduction_tol
        self.exact_curvature = exact_curvature
        self.free = free
        self.lam = np.asarray(wavelengths)
        self.w = jnp.asarray(weights)
        # Each variable's position x in [0, 1] of its range: linear, or (``logarithmic``) logarithmic
        # for the variables whose effects are multiplicative (prior coordinate "log": concentrations,
        # thickness, scales): theta = low + scale (exp(x log_span) - 1), scale = low for ranges that
        # exclude 0 (a pure logarithm) or 1e-3 of the range for ranges from 0 (logarithmic above
        # that, 0 reachable). In linear positions fits crawl along valleys that are straight in the
        # logarithms, such as melanin against a thin epidermis (their product sets its absorbance).
        self.logarithmic = np.array([VARIABLES[n].prior == "log" and logarithmic for n in free])
        low = np.array([VARIABLES[n].low for n in free])
        high = np.array([VARIABLES[n].high for n in free])
        self.low, self.span = jnp.asarray(low), jnp.asarray(high - low)
        self.scale = np.where(low > 0.0, low, 1e-3 * (high - low))
        self.log_span = np.where(self.logarithmic, np.log1p((high - low) / self.scale), 1.0)
        self.step_tol, self.stationarity_tol = step_tol, stationarity_tol

    def physical(self, x):
        """Physical values of positions x (..., f) in the ranges."""
        xp = np if isinstance(x, np.ndarray) else jnp
        logged = np.asarray(self.low) + self.scale * xp.expm1(xp.where(self.logarithmic, x, 0.0) * self.log_span)
        return xp.where(self.logarithmic, logged, np.asarray(self.low) + np.asarray(self.span) * x)

    def slope(self, x):
        """d theta / d x at positions x."""
        return jnp.where(self.logarithmic, self.scale * self.log_span * jnp.exp(jnp.where(self.logarithmic, x, 0.0) * self.log_span), self.span)

    def position(self, theta: np.ndarray) -> np.ndarray:
        """Positions in [0, 1] of physical values theta (..., f) (NumPy)."""
        low, span = np.asarray(self.low), np.asarray(self.span)
        logged = np.log1p(np.maximum(theta - low, 0.0) / self.scale) / self.log_span
        return np.clip(np.where(self.logarithmic, logged, (theta - low) / span), 0.0, 1.0)

    def _evaluate(self, measurement, x):
        """The model's evaluation (``MeasurementModel.evaluation``) at positions x and its Jacobian
        with respect to x: the costly part of an iteration."""
        return evaluate_with_jacobian(lambda z: measurement.evaluation_of_free(self.physical(z), self.lam), x)

    def _linearised(self, measurement, evaluation, target):
        """(residual, d residual / dx) from an evaluation and its Jacobian (``_evaluate``)."""
        return measurement.linearised_residual(*evaluation, target, self.lam, self.w)

    def _linearise(self, measurement, x, target):
        """(residual, d residual / dx) at positions x."""
        return self._linearised(measurement, self._evaluate(measurement, x), target)

    def _exact_curvature(self, measurement, x, target, r):
        """sum_i r_i Hessian(r_i) at x by automatic differentiation (about four Jacobians' cost for
        three variables): the Hessian of r(x) . r held fixed."""
        held = jax.lax.stop_gradient(r)
        weighted = lambda z: held @ measurement.residual_of_free(self.physical(z), target, self.lam, self.w)  # noqa: E731
        return jax.hessian(weighted)(x)

    def _model_step(self, state: LockstepState, damping):
        """The damped (quasi-)Newton step over the variables not held on a bound (not clipped), and
        the reduction of the cost its quadratic model predicts."""
        x, at = state.point, state.carry
        gradient = at.jacobian.T @ at.residual
        # held: on a bound, or within _ACTIVE_BAND of it, while the gradient pushes outward; such a
        # variable moves onto its bound and the step is solved over the others (Bertsekas's
        # projected Newton: a clipped full step need not lower the cost, and iterates that creep
        # towards a bound without reaching it converge only linearly)
        to_low = (x <= _ACTIVE_BAND) & (gradient > 0.0)
        to_high = (x >= 1.0 - _ACTIVE_BAND) & (gradient < 0.0)
        held = to_low | to_high
        onto_bound = jnp.where(to_low, -x, jnp.where(to_high, 1.0 - x, 0.0))
        keep = ~held
        normal = at.jacobian.T @ at.jacobian
        scale = jnp.maximum(jnp.diagonal(normal), 1e-12 * jnp.max(jnp.diagonal(normal)) + 1e-300)
        both = keep[:, None] & keep[None, :]

        def solve(hessian):
            system = jnp.where(both, hessian, 0.0) + jnp.diag(jnp.where(keep, damping * scale, 1.0))
            rhs = jnp.where(keep, -(gradient + hessian @ onto_bound), 0.0)
            step = solve_dominant(system, rhs[:, None])[:, 0] + onto_bound
            step = jnp.where(jnp.all(jnp.isfinite(step)), step, 0.0)
            return step, -(gradient @ step + 0.5 * step @ hessian @ step)

        step, predicted = solve(normal + at.curvature)
        fallback, predicted_gn = solve(normal)
        use_secant = predicted > 0.0
        return jnp.where(use_secant, step, fallback), 2.0 * jnp.where(use_secant, predicted, predicted_gn)

    def _trial(self, state: LockstepState):
        """The next point: the damped step, clipped to the box; and the reduction its model predicts."""
        step, predicted = self._model_step(state, state.carry.damping)
        return jnp.clip(state.point + jnp.clip(step, -0.5, 0.5), 0.0, 1.0), predicted

    def _iterate(self, measurement, state: LockstepState, target, count: int) -> LockstepState:
        """``count`` iterations (model evaluations) from ``state``; a state not entered yet (cost
        NaN: no linearisation) spends its first evaluation on its point.

        As in the warm start (``_spectra._Solver._iterate``), each loop step first decides on the
        trial the previous step evaluated, from the evaluation left in the loop's carry, then
        proposes and evaluates the next trial: the residual's Jacobian is formed from a carried
        buffer, which XLA does not fuse with the model (see ``MeasurementModel.evaluation``)."""

        def decide(state, trial, predicted, evaluation):
            r, jacobian = self._linearised(measurement, evaluation, target)
            cost = jnp.sum(r**2)
            entering = jnp.isnan(state.cost)
            better = entering | (jnp.isfinite(cost) & (cost <= state.cost))
            gain = (state.cost - cost) / jnp.maximum(predicted, 1e-300)
            # Nielsen's damping update: relax after steps the model predicted well
            relax = jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * jnp.clip(gain, 0.0, 1.0) - 1.0) ** 3)
            at = state.carry
            moved = jnp.where(entering, jnp.inf, jnp.where(better, jnp.max(jnp.abs(trial - state.point)), at.moved))
            if self.exact_curvature:
                curvature = self._exact_curvature(measurement, trial, target, r)
            else:
                update = _secant_update(at.curvature, trial - state.point, at.jacobian, at.residual, jacobian, r)
                curvature = jnp.where(entering, at.curvature, update)
            damping = jnp.where(entering, at.damping, jnp.maximum(at.damping * relax, 1e-12))
            new = LockstepState(trial, jnp.where(jnp.isfinite(cost), cost, jnp.inf), _Linearisation(r, jacobian, curvature, damping, moved))
            old = eqx.tree_at(lambda s: s.carry.damping, state, jnp.minimum(at.damping * 4.0, 1e12))
            return new.keep_where(better, old)

        def body(k, carry):
            state, trial, predicted, evaluation = carry
            # the first step has nothing to decide yet (k is not batched: a true branch, which spares
            # the exact stage a Hessian)
            state = jax.lax.cond(k > 0, decide, lambda state, *_: state, state, trial, predicted, evaluation)
            trial, predicted = self._trial(state)
            trial = jnp.where(jnp.isnan(state.cost), state.point, trial)
            return state, trial, predicted, self._evaluate(measurement, trial)

        evaluation = placeholder(lambda x: self._evaluate(measurement, x), state.point)
        carry = (state, state.point, jnp.zeros_like(state.cost), evaluation)
        return decide(*jax.lax.fori_loop(0, count, body, carry))

    def _converged(self, state: LockstepState):
        theta = self.physical(state.point)
        gradient = 2.0 * (state.carry.jacobian / self.slope(state.point)).T @ state.carry.residual
        stationary = stationarity(self.free, theta, gradient, state.cost) <= self.stationarity_tol
        # NL2SOL's relative function convergence: the full model step would lower the cost by no
        # more than reduction_tol of it. Unlike the first-order test it is invariant to each
        # variable's scale: a variable its data pin down (a large curvature) may keep a gradient
        # that no step can turn into a lower cost in floating point.
        predicted = self._model_step(state, jnp.asarray(_CONVERGENCE_DAMPING, state.cost.dtype))[1]
        reduced = jnp.isfinite(predicted) & (predicted <= self.reduction_tol * state.cost)
        return (state.carry.moved <= self.step_tol) | stationary | reduced

    @eqx.filter_jit
    def _round(self, measurement, state: LockstepState, target):
        """``ROUND_STEPS`` iterations of a batch of states; returns (states, converged)."""

        def one(state, target):
            state = self._iterate(measurement, state, target, ROUND_STEPS)
            return state, self._converged(state)

        return jax.vmap(one)(state, target)

    def run(self, measurement, theta0: np.ndarray, target: np.ndarray, max_steps: int, chunk_size: int, progress,
            fixed_batch: bool = False):
        """Polish physical values ``theta0`` (n, f) against ``target`` (n, m); returns
        (theta, iterations, converged). ``fixed_batch``: batches of ``chunk_size``, or of
        ``STRAGGLER_BATCH`` for the few left after the first rounds (two compiled programs per
        problem, whatever the counts; cheap models), else of the size that is left.

        Between rounds the unconverged are gathered and each carries its whole state (point,
        residual, Jacobian, secant curvature, damping): a round resumes where the last one ended,
        with no Jacobian spent on restarting. The first round spends its first evaluation on the
        starting points."""
        n, m = target.shape
        x = self.position(np.asarray(theta0, dtype=float))
        f = x.shape[1]
        rows = m + measurement.colour_rows + measurement.prior_rows
        unentered = LockstepState(x, np.full(n, np.nan), _Linearisation(
            np.zeros((n, rows)), np.zeros((n, rows, f)), np.zeros((n, f, f)), np.full(n, _INITIAL_DAMPING), np.full(n, np.inf)))
        leaves = jax.tree_util.tree_leaves(unentered)
        done = np.zeros(n, dtype=bool)
        steps = np.zeros(n, dtype=np.int64)
        todo = np.arange(n)

        def size(count):
            if not fixed_batch:
                return pad_size(count, chunk_size)
            return STRAGGLER_BATCH if count <= 2 * STRAGGLER_BATCH else chunk_size

        def resume(*arrays):
            state, converged = self._round(measurement, jax.tree_util.tree_unflatten(_STATE, arrays[:-1]), arrays[-1])
            return (*jax.tree_util.tree_leaves(state), converged)

        for _ in range(max(1, -(-max_steps // ROUND_STEPS))):
            if not todo.size:
                break
            # fixed_batch: batches of fixed sizes (padded), compiled once whatever is left; otherwise
            # the batch shrinks with what is left (for costly direct transport)
            *out, done[todo] = map_batches(resume, (*(a[todo] for a in leaves), target[todo]), size(todo.size), progress, "bounded fit")
            for full, part in zip(leaves, out):
                full[todo] = part
            steps[todo] += ROUND_STEPS
            todo = todo[~done[todo]]
        point = jax.tree_util.tree_unflatten(_STATE, leaves).point
        return self.physical(np.asarray(point)), steps, done


@eager_cache(maxsize=16)
def bounded_polish(free: tuple, wavelengths: tuple, weights: tuple, step_tol: float, stationarity_tol: float,
                   exact_curvature: bool = False, reduction_tol: float = 1e-10, logarithmic: bool = True) -> BoundedPolish:
    """One ``BoundedPolish`` per problem: its compiled rounds serve every later call (the
    measurement's values are arguments of them, not part of the instance)."""
    return BoundedPolish(free, wavelengths, weights, step_tol, stationarity_tol, exact_curvature, reduction_tol, logarithmic)


#: The structure of a polish state (its leaves travel between rounds as NumPy arrays).
_STATE = jax.tree_util.tree_structure(LockstepState(0, 0, _Linearisation(0, 0, 0, 0, 0)))


def _secant_update(curvature, step, jacobian, residual, new_jacobian, new_residual):
    """NL2SOL's structured secant update of S ~ sum_i r_i Hessian(r_i) along an accepted ``step``
    (Dennis, Gay & Welsch 1981): S s should equal (J_new - J)^T r_new; sized first by
    min(1, |s.y#| / |s.S s|); kept when the gradient change y has s.y > 0 (the update's condition)."""
    target = (new_jacobian - jacobian).T @ new_residual  # y#
    change = new_jacobian.T @ new_residual - jacobian.T @ residual  # y
    s_y = step @ change
    s_s_s = step @ curvature @ step
    size = jnp.where(jnp.abs(s_s_s) > 0.0, jnp.minimum(1.0, jnp.abs(step @ target) / jnp.where(s_s_s != 0.0, jnp.abs(s_s_s), 1.0)), 1.0)
    curvature = size * curvature
    v = target - curvature @ step
    denominator = jnp.where(s_y > 0.0, s_y, 1.0)
    update = (jnp.outer(v, change) + jnp.outer(change, v)) / denominator - (v @ step) * jnp.outer(change, change) / denominator**2
    ok = (s_y > 1e-12 * jnp.sqrt((step @ step) * (change @ change))) & jnp.all(jnp.isfinite(update))
    return jnp.where(ok, curvature + update, curvature)

