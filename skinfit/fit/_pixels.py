"""Per-pixel inversion of linear RGB pixels to melanin, haemoglobin and shading: the solver.

Camera model: a pixel's linear sRGB (D65 white = 1) is

    rgb = gains * shading * M W R(lambda; C_m, beta_m, C_h)

with R the skin model's diffuse reflectance at 400-700 nm / 10 nm, W the CIE 1931 2-degree colour
matching functions weighted by the illuminant (D65 by default, Bradford-adapted to D65 otherwise),
M the XYZ -> linear sRGB matrix (``skinfit.colorimetry``) and gains the camera's white balance.
Three channels carry three unknowns per pixel: C_m, C_h and the shading; the melanin blend and the
gains are one value for the whole image (given, or fitted once by ``skinfit.fit``).

``fit_pixels``, per pixel, over fixed-size chunks compiled once:

1. warm start: the inverse table (``skinfit.colorimetry``) gives one or two starts from the
   pixel's chromaticity, each refined by a Newton step in chromaticity; the second (a second
   branch of the fold) only where it differs;
2. solve: Levenberg-Marquardt in lock-step on the model's colour spline (exact to ~3e-7 in linear
   sRGB), with the shading eliminated in closed form (variable projection: for a colour m the best
   shading is t.m / m.m), the residual relative to the pixel's brightness so that dark and bright
   pixels weigh alike, the prior on ln C_m and ln C_h as two more residual rows (MAP; weights 0
   without one), and the roots projected onto the box; converged when the undamped Gauss-Newton
   step still to go is at most ``step_tol``. The others are gathered for more steps, Newton's
   (the residuals' exact curvature from the spline's second derivatives: colours the model misses
   near the fold converge quadratically there, not linearly), and what remains goes to
   optimistix's Levenberg-Marquardt;
3. optionally (``exact_steps``), Gauss-Newton steps on the exact forward model remove the
   spline's last ~1e-7.

Where both branches fit, the one whose shading is nearest a reference wins. Pixels that cannot be
fitted get a status code and zeros, never NaN. ``skinfit.fit`` builds whole images on it.
"""

from __future__ import annotations

import enum

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._batching import bucket_size, map_batches, pad_size
from .._exported import persistent_jit
from .._validate import SkinfitInputError
from ..colorimetry import (
    DEFAULT_ILLUMINANT,
    ColourTable,
    colour_table,
    delta_e2000,
    linear_srgb_to_lab,
    model_rgb,
    spline_channels,
    spline_rgb,
    warm_starts,
)
from ..model import SkinModel, cache_key, model_with_options
from ._lockstep import LockstepState


class PixelStatus(enum.IntEnum):
    """Per-pixel outcome of ``fit_pixels``."""

    SUCCESS = 0  #: converged; maps hold the fit
    MAX_STEPS = 1  #: stopped at the step limit; maps hold the best iterate
    OUT_OF_MODEL = 2  #: the best fit misses the pixel by more than ``max_delta_e`` CIEDE2000 (not skin?)
    BAD_INPUT = 3  #: NaN, Inf or negative values
    MASKED = 4  #: outside the mask
    BLACK = 5  #: too dark to carry colour
    SATURATED = 6  #: a channel at the clipping level
    NOT_SKIN = 7  #: fitted only by parameters no skin has (hair, brows, lips, cloth): pinned at the box's edge or far outside the population prior
    SPECULAR = 8  #: a glint: the neighbourhood's skin colour plus white light, not a diffuse skin colour


def _spline_colour(coefficients, second: bool = False):
    """Colour of the spline at roots u, v (n,): (value, d/du, d/dv), each a tuple of 3 channels;
    with ``second`` also (d2/du2, d2/du dv, d2/dv2) (Newton steps, ``_projected``)."""

    def colour(u, v):
        channels = spline_channels(coefficients, u, v, second=second)
        return tuple(tuple(channel[i] for channel in channels) for i in range(len(channels[0])))

    return colour


def _exact_colour(melanin_blend, melanin_max, haemoglobin_max, weights, model):
    """The exact model's colour at roots u, v (n,), in the layout of ``_spline_colour``."""

    def one(roots):
        colour = lambda r: model_rgb(r[None], melanin_blend, melanin_max, haemoglobin_max, weights, model)[0]  # noqa: E731
        value, du = jax.jvp(colour, (roots,), (jnp.array([1.0, 0.0], roots.dtype),))
        dv = jax.jvp(colour, (roots,), (jnp.array([0.0, 1.0], roots.dtype),))[1]
        return value, du, dv

    def colour(u, v):
        return tuple(tuple(a[:, c] for c in range(3)) for a in jax.vmap(one)(jnp.stack([u, v], axis=-1)))

    return colour


def _dot3(a, b):
    """Dot product of two colours held as 3-tuples of (n,) channels, written out."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


class _Normal(eqx.Module):
    """What a pixel's iterate carries besides its roots and cost (each (n,)): the 2x2 normal
    equations J^T J (uu, uv, vv) and J^T r (gu, gv) of the relative residual r (shading
    eliminated), the best shading and the model colour (3 channels); for Newton steps also the
    residuals' own curvature S = sum_i r_i Hessian(r_i) (suu, suv, svv), None otherwise."""

    uu: jax.Array
    uv: jax.Array
    vv: jax.Array
    gu: jax.Array
    gv: jax.Array
    shading: jax.Array
    colour: tuple
    curvature: tuple | None = None


def _projected(colour, u, v, target, scale, prior) -> LockstepState:
    """Variable projection at roots u, v (n,): relative residual r = (t - k m) |t|^-1 with the best
    shading k = t.m / m.m, and the prior's rows (``_prior_rows``), reduced to the normal
    equations of the two roots: a ``LockstepState`` with point (u, v), the cost |r|^2 and a ``_Normal``
    carry. Only these ten numbers per pixel travel between steps: carrying r and J (13 more) made
    every kept-or-refused selection recompute the residual.

    A ``colour`` that also returns second derivatives (``_spline_colour(..., second=True)``) adds
    the residuals' exact curvature S (three numbers more), for Newton steps (``_step``)."""
    m, dm_u, dm_v, *second = colour(u, v)
    mm = _dot3(m, m)
    tm = _dot3(target, m)
    k = tm / mm

    r = tuple((t - k * c) * scale for t, c in zip(target, m))

    def d_shading(dm):
        return _dot3(target, dm) / mm - tm * 2.0 * _dot3(m, dm) / (mm * mm)

    dk_u, dk_v = d_shading(dm_u), d_shading(dm_v)
    ju, jv = (tuple(-(dk * c + k * d) * scale for c, d in zip(m, dm)) for dk, dm in ((dk_u, dm_u), (dk_v, dm_v)))
    cost, uu, uv, vv, gu, gv = _dot3(r, r), _dot3(ju, ju), _dot3(ju, jv), _dot3(jv, jv), _dot3(ju, r), _dot3(jv, r)
    # the prior's rows w (log root - c): d/du = w / u
    centre_u, centre_v, weight_u, weight_v, centre_k, weight_k = prior
    row_u, row_v = weight_u * (jnp.log(u) - centre_u), weight_v * (jnp.log(v) - centre_v)
    cost, gu, gv = cost + row_u * row_u + row_v * row_v, gu + weight_u / u * row_u, gv + weight_v / v * row_v
    uu, vv = uu + (weight_u / u) ** 2, vv + (weight_v / v) ** 2
    # the shading's row w (ln k - c) (an albedo capture: shading known up to one scale); 0 weight: none
    safe_k = jnp.maximum(k, 1e-30)
    row_k, a_u, a_v = weight_k * (jnp.log(safe_k) - centre_k), weight_k * dk_u / safe_k, weight_k * dk_v / safe_k
    cost, gu, gv = cost + row_k * row_k, gu + a_u * row_k, gv + a_v * row_k
    uu, uv, vv = uu + a_u * a_u, uv + a_u * a_v, vv + a_v * a_v
    curvature = None
    if second:
        curvature = _residual_curvature(target, scale, m, mm, tm, (dm_u, dm_v), second, k, (dk_u, dk_v), r,
                                        (u, v, weight_u, weight_v, row_u, row_v), (safe_k, weight_k, row_k))
    return LockstepState((u, v), cost, _Normal(uu, uv, vv, gu, gv, k, m, curvature))


def _residual_curvature(target, scale, m, mm, tm, dm, d2m, k, dk, r, root_rows, shading_row):
    """S = sum_i r_i Hessian(r_i) over the colour rows r = (t - k m) scale (k = t.m / m.m, the
    shading eliminated; mm = m.m and tm = t.m as ``_projected`` has them), the roots' prior rows
    and the shading's row: (suu, suv, svv), each (n,).

    With N = t.m and D = m.m, k_ab = N_ab / D - (N_a D_b + N_b D_a) / D^2 - N D_ab / D^2
    + 2 N D_a D_b / D^3; a colour row's Hessian is -scale (k_ab m + k_a m_b + k_b m_a + k m_ab).
    A prior row w (ln u - c) has second derivative -w / u^2, the shading's row
    w (k_ab / k - k_a k_b / k^2)."""
    (dm_u, dm_v), (dm_uu, dm_uv, dm_vv), (dk_u, dk_v) = dm, d2m, dk
    d_mm = {"u": 2.0 * _dot3(m, dm_u), "v": 2.0 * _dot3(m, dm_v)}
    d_tm = {"u": _dot3(target, dm_u), "v": _dot3(target, dm_v)}
    first = {"u": dm_u, "v": dm_v}
    rm = {"u": _dot3(r, dm_u), "v": _dot3(r, dm_v)}
    r_dot_m, slope = _dot3(r, m), {"u": dk_u, "v": dk_v}
    u, v, weight_u, weight_v, row_u, row_v = root_rows
    safe_k, weight_k, row_k = shading_row

    def entry(a, b, d2):
        d2_tm = _dot3(target, d2)
        d2_mm = 2.0 * (_dot3(first[a], first[b]) + _dot3(m, d2))
        k_ab = (d2_tm / mm - (d_tm[a] * d_mm[b] + d_tm[b] * d_mm[a]) / mm**2 - tm * d2_mm / mm**2
                + 2.0 * tm * d_mm[a] * d_mm[b] / mm**3)
        colour_rows = -scale * (k_ab * r_dot_m + slope[a] * rm[b] + slope[b] * rm[a] + k * _dot3(r, d2))
        return colour_rows + row_k * weight_k * (k_ab / safe_k - slope[a] * slope[b] / safe_k**2)

    return (entry("u", "u", dm_uu) - row_u * weight_u / u**2, entry("u", "v", dm_uv),
            entry("v", "v", dm_vv) - row_v * weight_v / v**2)


#: Lower bound of the roots in the solver: C = max * root^2 has zero slope at root 0, which would
#: trap a pixel there (the cost is even in the root); 1e-3 means C_m >= 5e-7, C_h >= 1.5e-7.
_ROOT_FLOOR = 1e-3


def _step(state: LockstepState, damping, newton: bool = True):
    """The damped Gauss-Newton step (Marquardt's scaling) projected on the box: a root on a bound
    that its step pushes out of the box stays there and the other takes its own one-variable step
    (clipping the joint step instead stalls on the bound).

    Where the state carries the residuals' curvature S (and ``newton``), the damped Newton step
    (J^T J + S + damping diag(J^T J)) instead, where that matrix is positive definite (elsewhere
    Gauss-Newton's): colours the model misses by ~1 % near the fold, where J^T J is nearly
    singular, converge quadratically instead of linearly (measured on a real capture's
    regularised refit: 4,884 of 33,618 stragglers left after one two-step round, not 19,348)."""
    (u, v), n = state.point, state.carry
    floor = 1e-12 * jnp.maximum(n.uu, n.vv) + 1e-300  # against a dead direction
    gauss_newton = _box_step(u, v, n.uu * (1.0 + damping) + floor, n.uv, n.vv * (1.0 + damping) + floor, n.gu, n.gv)
    if not newton or n.curvature is None:
        return gauss_newton
    suu, suv, svv = n.curvature
    du, dv, uv = n.uu * (1.0 + damping) + suu + floor, n.vv * (1.0 + damping) + svv + floor, n.uv + suv
    positive = (du > 0.0) & (dv > 0.0) & (du * dv - uv * uv > 1e-12 * jnp.maximum(du, dv) ** 2)
    safe = lambda a: jnp.where(positive, a, 1.0)  # noqa: E731  (no division by an indefinite pivot)
    newton_u, newton_v = _box_step(u, v, safe(du), jnp.where(positive, uv, 0.0), safe(dv), n.gu, n.gv)
    return jnp.where(positive, newton_u, gauss_newton[0]), jnp.where(positive, newton_v, gauss_newton[1])


def _box_step(u, v, du, uv, dv, gu, gv):
    """The step s solving [[du, uv], [uv, dv]] s = -(gu, gv) (each (n,)) projected on the box
    (``_step``); 0 where it is not finite."""
    det = du * dv - uv * uv
    step_u, step_v = -(dv * gu - uv * gv) / det, -(du * gv - uv * gu) / det
    out_u = ((u <= _ROOT_FLOOR) & (step_u < 0.0)) | ((u >= 1.0) & (step_u > 0.0))
    out_v = ((v <= _ROOT_FLOOR) & (step_v < 0.0)) | ((v >= 1.0) & (step_v > 0.0))
    step_u, step_v = jnp.where(out_v, -gu / du, step_u), jnp.where(out_u, -gv / dv, step_v)
    step_u, step_v = jnp.where(out_u, 0.0, step_u), jnp.where(out_v, 0.0, step_v)
    finite = jnp.isfinite(step_u) & jnp.isfinite(step_v)
    return jnp.where(finite, step_u, 0.0), jnp.where(finite, step_v, 0.0)


def _stationary(state: LockstepState, tol=1e-4):
    """First-order optimality on the box: each free column of the Jacobian orthogonal to the
    residual to within ``tol`` (cosine); a column at a bound that the gradient pushes out of the
    box counts as orthogonal. At cosine c the step still to go is ~ c |r| / |J|: 1e-4 leaves
    ~1e-6 in the roots for the 1 % residuals of colours just outside the gamut."""
    norm_r = jnp.sqrt(state.cost)
    (u, v), n = state.point, state.carry

    def free_cosine(g, jj, x):  # g: the cost's half-gradient along this root, jj = |J column|^2
        blocked = ((x <= _ROOT_FLOOR) & (g > 0.0)) | ((x >= 1.0) & (g < 0.0))
        return jnp.where(blocked, 0.0, jnp.abs(g) / (jnp.sqrt(jj) * norm_r + 1e-300))

    return jnp.maximum(free_cosine(n.gu, n.uu, u), free_cosine(n.gv, n.vv, v)) <= tol


def _gauss_newton(colour, roots, target, damping, steps, prior):
    """``steps`` Levenberg-Marquardt steps in lock-step over pixels (n, 3) from roots (n, 2) with
    the damping (n,) they start with (a straggler goes on with the damping it stopped at).

    Each step solves the 2x2 damped normal equations, projects the step onto the box and keeps it
    only if the cost does not rise; the damping falls after a kept step and rises after a refused
    one (under heavy melanin the haemoglobin direction is weak and undamped Gauss-Newton
    overshoots). ``remaining`` estimates each pixel's distance to the optimum in the roots: the
    undamped step from the final point (Gauss-Newton converges quadratically, so after it the
    error would be ~its square), or 0 where the point is first-order stationary (colours outside
    the gamut, where the steps shrink only linearly).

    ``prior`` (n, 6): per pixel the centres and weights of the prior rows (``_prior_rows``).
    A ``colour`` with second derivatives makes the steps Newton's (``_step``).

    Returns the roots (n, 2), the shading, ``remaining``, the square root of the cost (relative
    residual and prior rows) (each (n,)), the fitted colour (n, 3), the damping (n,) and the
    Gauss-Newton normal matrix (uu, uv, vv) (n, 3) for standard errors.
    """
    target = (target[:, 0], target[:, 1], target[:, 2])
    scale = 1.0 / jnp.sqrt(_dot3(target, target))
    prior = tuple(prior[:, i] for i in range(6))

    def step(_, carried):
        state, damping = carried
        (u, v), (step_u, step_v) = state.point, _step(state, damping)
        trial = _projected(colour, jnp.clip(u + step_u, _ROOT_FLOOR, 1.0), jnp.clip(v + step_v, _ROOT_FLOOR, 1.0), target, scale, prior)
        keep = trial.cost <= state.cost
        state = trial.keep_where(keep, state)
        return state, jnp.where(keep, jnp.maximum(damping * 0.1, 1e-9), jnp.minimum(damping * 10.0, 1e9))

    start = jnp.clip(roots, _ROOT_FLOOR, 1.0)
    start = _projected(colour, start[:, 0], start[:, 1], target, scale, prior)
    state, damping = jax.lax.fori_loop(0, steps, step, (start, damping))
    step_u, step_v = _step(state, 0.0, newton=False)  # the same estimate whichever steps were taken
    remaining = jnp.where(_stationary(state), 0.0, jnp.maximum(jnp.abs(step_u), jnp.abs(step_v)))
    n = state.carry
    fitted = jnp.stack([n.shading * c for c in n.colour], axis=-1)
    normal = jnp.stack([n.uu, n.uv, n.vv], axis=-1)
    return jnp.stack(state.point, axis=-1), n.shading, remaining, jnp.sqrt(state.cost), fitted, damping, normal


#: Levenberg-Marquardt's first damping: the affine warm starts are close enough that Gauss-Newton
#: rarely overshoots from them; a refused step raises it tenfold.
_INITIAL_DAMPING = 1e-5


@persistent_jit
def _spline_chunk(coefficients, roots, target, damping, prior, steps):
    return _gauss_newton(_spline_colour(coefficients), roots, target, damping, steps, prior)


@persistent_jit
def _newton_chunk(coefficients, roots, target, damping, prior, steps):
    """``_spline_chunk`` with Newton steps (the residuals' exact curvature): for the stragglers."""
    return _gauss_newton(_spline_colour(coefficients, second=True), roots, target, damping, steps, prior)


@persistent_jit
def _first_pass_chunk(coefficients, inverse, target, prior, steps):
    """Warm starts and ``steps`` steps from the first; also the second start (n, 2) for a retry
    and whether it differs from the first (n,)."""
    starts = warm_starts(inverse, target)
    damping = jnp.full(len(target), _INITIAL_DAMPING, target.dtype)
    solved = _gauss_newton(_spline_colour(coefficients), starts[:, 0], target, damping, steps, prior)
    return (*solved, starts[:, 1], jnp.any(starts[:, 0] != starts[:, 1], axis=-1))


def _goes_on(remaining, residual, before, step_tol):
    """Whether a straggler goes round again (NumPy or JAX arrays): more than ``step_tol`` still to
    go, and a cost below ``_HOPELESS_RESIDUAL`` or one that fell by ``_DESCENDING`` from ``before``
    in the last round."""
    return (remaining > step_tol) & ((residual <= _HOPELESS_RESIDUAL) | (residual < _DESCENDING * before))


@persistent_jit
def _straggler_tail(coefficients, roots, target, damping, prior, steps, rounds, step_tol):
    """Rounds of ``steps`` steps, at most ``rounds``, for pixels (one chunk) while ``_goes_on``;
    a pixel that stops keeps its state. The same arithmetic per pixel
    as the gathered rounds of ``_solve``; returns ``_gauss_newton``'s outputs and which pixels
    would still go on (n,)."""
    colour = _spline_colour(coefficients, second=True)  # Newton steps, as the gathered rounds
    first = _gauss_newton(colour, roots, target, damping, 0, prior)  # the pixels' state, no step
    moving = jnp.ones(len(roots), bool)

    def go_on(carried):
        count, _, moving = carried
        return (count < rounds) & jnp.any(moving)

    def one_round(carried):
        count, state, moving = carried
        new = _gauss_newton(colour, state[0], target, state[5], steps, prior)
        state = tuple(jnp.where(moving.reshape(-1, *([1] * (a.ndim - 1))), b, a) for a, b in zip(state, new))
        moving = moving & _goes_on(new[2], new[3], carried[1][3], step_tol)
        return count + 1, state, moving

    _, state, moving = jax.lax.while_loop(go_on, one_round, (jnp.asarray(0), first, moving))
    return (*state, moving)


#: Pixels per chunk of the Levenberg-Marquardt fallback.
_LM_CHUNK = 256

#: Chunk of a tail of few stragglers (the gathered rounds use ``_SUBSET_CHUNK``), and the number
#: of stragglers at which the rounds go on inside ``_straggler_tail``.
_TAIL_CHUNK = 256
_TAIL_FROM = 2048


#: Pixels per chunk of the exact transport polish (measured: ~2.2 MB of device memory per pixel).
_TRANSPORT_CHUNK = 1024


@eqx.filter_jit
def _exact_chunk(exact_model, roots, target, prior, steps):
    damping = jnp.full(len(roots), _INITIAL_DAMPING, roots.dtype)
    return _gauss_newton(_exact_colour(*exact_model), roots, target, damping, steps, prior)


@persistent_jit
def _delta_e_chunk(measured, fitted):
    return (delta_e2000(linear_srgb_to_lab(measured), linear_srgb_to_lab(fitted)),)


@persistent_jit(static_argnums=(4, 5, 6))  # max_steps, rtol, atol
def _levenberg_marquardt(coefficients, roots, target, prior, max_steps, rtol, atol):
    """optimistix Levenberg-Marquardt on the spline for the pixels the lock-step solver left
    moving, with the same prior rows; the box by clipping inside the residual (a pixel that ends
    outside sits on the bound its gradient pushes it to)."""

    def residual(z, args):
        t, prior = args
        z = jnp.clip(z, _ROOT_FLOOR, 1.0)
        m = spline_rgb(coefficients, z[None])[0][0]
        k = jnp.dot(t, m) / jnp.dot(m, m)
        shading_row = prior[5:6] * (jnp.log(jnp.maximum(k, 1e-30)) - prior[4:5])
        return jnp.concatenate([(t - k * m) / jnp.linalg.norm(t), prior[2:4] * (jnp.log(z) - prior[:2]), shading_row])

    def one(r0, t, p):
        solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
        sol = optx.least_squares(residual, solver, r0, args=(t, p), max_steps=max_steps, throw=False)
        z = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, r0)
        return jnp.clip(z, 0.0, 1.0), sol.result == optx.RESULTS.successful

    return jax.vmap(one)(roots, target, prior)


def fit_pixels(
    linear_rgb: np.ndarray,
    *,
    melanin_blend: float = 0.7,
    illuminant: str = DEFAULT_ILLUMINANT,
    mask: np.ndarray | None = None,
    steps: int = 1,
    straggler_steps: int = 2,
    max_straggler_rounds: int = 48,
    lm_max_steps: int = 64,
    exact_steps: int = 0,
    step_tol: float = 1e-7,
    shading_reference: float | None = None,
    max_delta_e: float = 1.0,
    black_level: float = 1e-4,
    saturation_level: float = 0.999,
    chunk_size: int = 32768,
    progress: bool | None = None,
    table: ColourTable | None = None,
    method: str | None = None,
    model: SkinModel | None = None,
    white_balance: tuple[float, float, float] | None = None,
    prior: bool | None = None,
    colour_noise: float = 0.003,
    prior_mean: np.ndarray | None = None,
    prior_sd: np.ndarray | None = None,
    initial: tuple[np.ndarray, np.ndarray] | None = None,
    shading_prior: tuple | None = None,
) -> dict[str, np.ndarray]:
    """Fit every pixel of a linear sRGB image (h, w, 3) (or pixels (n, 3)).

    Args:
        steps: Levenberg-Marquardt steps for every pixel; ``straggler_steps`` more, up to
            ``max_straggler_rounds`` times, for those whose estimated distance to the optimum
            (the undamped Gauss-Newton step, in normalised roots) is above ``step_tol``, then up
            to ``lm_max_steps`` of optimistix's Levenberg-Marquardt.
        exact_steps: Gauss-Newton steps on the exact model after the spline fit (0: none).
        shading_reference: the shading that decides between the fold's branches (default: the
            median shading of the pixels with one branch).
        max_delta_e: CIEDE2000 above which a pixel is ``OUT_OF_MODEL`` (default 1, about a
            just-noticeable difference: the skin model cannot reproduce the pixel).
        black_level, saturation_level: linear values below / at or above which a pixel is
            ``BLACK`` / ``SATURATED`` (judged on the values given, before ``white_balance``).
        table: a ``colour_table(...)`` of another resolution (spline nodes, inverse cells) to use
            instead of the default one; its blend, illuminant and model must match.
        model: the ``SkinModel`` (default: the package default); ``method`` overrides its forward
            method (``"transport"``: tabulated adding-doubling; ``"transport-direct"``: the direct
            solve, whose colour table takes minutes on a laptop CPU, once per process and blend). The colour spline and the ``exact_steps`` use it.
        white_balance: per-channel camera gains the pixels carry: the skin model is fitted to the
            pixels divided by them (``fitted_rgb`` is without them).

        prior: fit the maximum a posteriori estimate under a Gaussian prior on (ln C_m, ln C_h)
            (default: where the model has a population prior, i.e. the calibrated model);
            ``False``: maximum likelihood (exact round trips of the model's own colours).
        colour_noise: relative RMS error of a channel (linear values) that the fit allows: what weighs
            the prior against the colour, and the scale of the standard errors. The default 0.3 %
            is about 8-bit quantisation of mid-tones; a larger value trusts the prior more (1 %:
            the fit departs from the colour by CIEDE2000 ~0.3 to reach likelier parameters).
        prior_mean, prior_sd: (2,) or per pixel (..., 2) mean and standard deviation of
            (ln C_m, ln C_h) that replace the model's population prior (spatial regularisation
            passes the neighbourhood's values here).
        shading_prior: (shading, sd) : a prior on ln shading, normal about ln shading (one value
            or one per pixel) with standard deviation sd: what an albedo capture knows (its shading
            is one scale for the image); None (default): the shading is free.
        initial: (C_m, C_h), each of the input's leading shape, to start from instead of the
            inverse table's warm starts (a refit from an earlier fit: its branch is kept).

    Returns maps of the input's leading shape: ``melanin``, ``melanin_blend``, ``haemoglobin``,
    ``shading``, ``residual_dE2000``, ``status`` (``PixelStatus``), ``fitted_rgb`` (..., 3), and
    ``melanin_se``, ``haemoglobin_se``: Laplace standard errors (the Gauss-Newton posterior at the fit,
    with ``colour_noise``), 0 where nothing was fitted.
    """
    rgb = np.asarray(linear_rgb, dtype=float)
    if rgb.ndim < 2 or rgb.shape[-1] != 3:
        raise SkinfitInputError(f"expected RGB pixels of shape (..., 3), got {rgb.shape}")
    if rgb.size == 0:
        raise SkinfitInputError("the image is empty")
    shape = rgb.shape[:-1]
    pixels = rgb.reshape(-1, 3)
    status, clean = screen_pixels(pixels, mask, black_level, saturation_level)
    if white_balance is not None:
        gains = np.asarray(white_balance, dtype=float)
        if gains.shape != (3,) or not np.all(gains > 0):
            raise SkinfitInputError(f"white_balance must be three positive gains, got {white_balance}")
        clean = clean / gains

    model = model_with_options(model, method=method)
    if table is None:
        table = colour_table(float(melanin_blend), illuminant, model=model)
    elif (table.melanin_blend, table.illuminant, cache_key(table.model)) != (float(melanin_blend), illuminant, cache_key(model)):
        raise SkinfitInputError("the colour table's melanin_blend, illuminant and model must match the fit's")
    todo = np.flatnonzero(status == 0)
    n = len(pixels)
    rows = _prior_rows(model, table, n, prior, colour_noise, prior_mean, prior_sd, shading_prior)
    if shading_reference is not None and np.ndim(shading_reference):
        shading_reference = np.broadcast_to(np.asarray(shading_reference, dtype=float), shape).reshape(-1)[todo]
    roots, shading, remaining, delta_e, fitted = np.zeros((n, 2)), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros((n, 3))
    normal = np.zeros((n, 3))
    if initial is not None:
        initial = np.stack([np.sqrt(np.clip(np.asarray(c, dtype=float).reshape(-1) / top, 0.0, 1.0))
                            for c, top in zip(initial, (table.melanin_max, table.haemoglobin_max))], axis=-1)[todo]
    if todo.size:
        solved = _solve(
            table, clean[todo], rows[todo], steps, straggler_steps, max_straggler_rounds, lm_max_steps, step_tol,
            shading_reference, bucket_size(todo.size, chunk_size), progress, initial,
        )
        if exact_steps:
            exact_model = table.model_arguments()
            exact = lambda t, r, p: _exact_chunk(exact_model, r, t, p, exact_steps)  # noqa: E731
            # a direct transport Jacobian holds ~2 MB per pixel (doubling loops): smaller chunks
            direct = model.method.solves_directly
            size = pad_size(todo.size, min(chunk_size, _TRANSPORT_CHUNK) if direct else chunk_size)
            polished = map_batches(exact, (clean[todo], solved[0], rows[todo]), size, progress, "exact polish")
            # converged: the spline fit had, and the exact steps leave at most step_tol to go
            polished[2] = np.where(solved[2] <= step_tol, polished[2], np.inf)
            solved = polished[:5] + [polished[6]]
        roots[todo], shading[todo], remaining[todo], _, fitted[todo], normal[todo] = solved
        (delta_e[todo],) = map_batches(_delta_e_chunk, (clean[todo], fitted[todo]), bucket_size(todo.size, chunk_size))
        status[todo[remaining[todo] > step_tol]] = PixelStatus.MAX_STEPS
        # a colour the model misses by more than max_delta_e is not skin as the camera model sees
        # it, whether or not the solver settled (colours far outside the gamut settle slowly)
        status[todo[delta_e[todo] > max_delta_e]] = PixelStatus.OUT_OF_MODEL
    fitted_any = np.isin(status, (PixelStatus.SUCCESS, PixelStatus.MAX_STEPS, PixelStatus.OUT_OF_MODEL))
    melanin, haemoglobin = table.parameters(roots)
    melanin_se, haemoglobin_se = _standard_errors(table, roots, normal, colour_noise)
    maps = {
        "melanin": melanin,
        "melanin_blend": np.full(n, float(melanin_blend)),
        "haemoglobin": haemoglobin,
        "shading": shading,
        "residual_dE2000": delta_e,
        "melanin_se": melanin_se,
        "haemoglobin_se": haemoglobin_se,
    }
    for values in maps.values():
        values[~fitted_any] = 0.0
    fitted[~fitted_any] = 0.0
    maps["status"] = status
    maps["fitted_rgb"] = fitted
    return {k: v.reshape(*shape, *v.shape[1:]) for k, v in maps.items()}


def _prior_rows(model, table, n, prior, colour_noise, mean, sd, shading_prior=None) -> np.ndarray:
    """The solver's prior rows (n, 6): centres of ln u, ln v and weights colour_noise / sd(ln u)
    (u = sqrt(C / C_max), so ln u = (ln C - ln C_max) / 2); weights 0 without a prior; then the
    shading's, the centre of ln k and colour_noise / sd(ln k) from ``shading_prior`` (shading, sd
    of its ln; the shading one value or (n,)), 0 without one."""
    population = model.prior
    if prior is None:
        prior = population is not None or mean is not None
    rows = np.zeros((n, 6))
    if shading_prior is not None:
        centre, sd_ln = shading_prior
        centre = np.broadcast_to(np.asarray(centre, dtype=float), (n,))
        if not (np.all(centre > 0) and sd_ln > 0 and colour_noise > 0):
            raise SkinfitInputError("shading_prior needs a positive shading and standard deviation")
        rows[:, 4], rows[:, 5] = np.log(centre), colour_noise / sd_ln
    if not prior:
        return rows
    if mean is None or sd is None:
        if population is None:
            raise SkinfitInputError("prior=True needs a model with a population prior (the calibrated model) or prior_mean and prior_sd")
        moments = np.array([population.moments(name) for name in ("melanin", "haemoglobin")])
        mean = moments[:, 0] if mean is None else mean
        sd = moments[:, 1] if sd is None else sd
    if not colour_noise > 0:
        raise SkinfitInputError(f"colour_noise must be positive, got {colour_noise}")
    mean = np.broadcast_to(np.asarray(mean, dtype=float), (*np.shape(mean)[:-1], 2)).reshape(-1, 2)
    sd = np.broadcast_to(np.asarray(sd, dtype=float), (*np.shape(sd)[:-1], 2)).reshape(-1, 2)
    if not np.all(sd > 0):
        raise SkinfitInputError("prior_sd must be positive")
    maxima = np.log([table.melanin_max, table.haemoglobin_max])
    rows[:, :2] = (mean - maxima) / 2.0
    rows[:, 2:4] = colour_noise / (sd / 2.0)
    return rows


def _standard_errors(table, roots, normal, colour_noise):
    """Laplace standard errors of C_m, C_h (each (n,)) from the roots' Gauss-Newton normal matrix
    (uu, uv, vv) (n, 3): the roots' covariance is colour_noise^2 (J^T J)^-1, and C = C_max u^2."""
    uu, uv, vv = normal[:, 0], normal[:, 1], normal[:, 2]
    det = uu * vv - uv * uv
    with np.errstate(divide="ignore", invalid="ignore"):
        se_u = colour_noise * np.sqrt(np.where(det > 0, vv / det, np.inf))
        se_v = colour_noise * np.sqrt(np.where(det > 0, uu / det, np.inf))
    # an unidentified direction reports the whole box rather than Inf
    se_u, se_v = np.minimum(np.nan_to_num(se_u, nan=1.0, posinf=1.0), 1.0), np.minimum(np.nan_to_num(se_v, nan=1.0, posinf=1.0), 1.0)
    return 2.0 * table.melanin_max * roots[:, 0] * se_u, 2.0 * table.haemoglobin_max * roots[:, 1] * se_v


def screen_pixels(pixels, mask, black_level, saturation_level):
    """Status of pixels (n, 3) before fitting (``SUCCESS``: to be fitted) and the pixels with
    non-finite values zeroed."""
    # column by column: NumPy reduces over a last axis of 3 several times slower
    columns = pixels[:, 0], pixels[:, 1], pixels[:, 2]
    finite = np.isfinite(columns[0]) & np.isfinite(columns[1]) & np.isfinite(columns[2])
    negative = (columns[0] < 0) | (columns[1] < 0) | (columns[2] < 0)
    clean = pixels if finite.all() else np.where(finite[:, None], pixels, 0.0)
    brightest = np.maximum(np.maximum(clean[:, 0], clean[:, 1]), clean[:, 2])
    status = np.select(
        [~finite | negative, brightest < black_level, brightest >= saturation_level],
        [PixelStatus.BAD_INPUT, PixelStatus.BLACK, PixelStatus.SATURATED],
        PixelStatus.SUCCESS,
    ).astype(np.uint8)
    if mask is not None:
        mask = np.asarray(mask).reshape(-1)
        if mask.shape[0] != len(pixels):
            raise SkinfitInputError(f"mask has {mask.shape[0]} pixels, the image {len(pixels)}")
        status[(status == 0) & ~(mask > 0)] = PixelStatus.MASKED
    return status, clean


def _solve(table, target, prior, steps, straggler_steps, max_rounds, lm_max_steps, step_tol, reference, size, progress, initial=None):
    """The spline fit of pixels (n, 3) under the prior rows (n, 6): warm starts (or the roots
    ``initial`` (n, 2)), lock-step steps, the second branch where it may win, stragglers. ``reference``: the shading (one value or per
    pixel) that chooses between the fold's branches (None: the median of single-branch pixels).
    Returns roots, shading, the distance still to go, the root cost, the fitted colour and the
    normal matrix (n, 3)."""
    coefficients = jnp.asarray(table.coefficients)
    spline = lambda count: lambda t, r, d, p: _spline_chunk(coefficients, r, t, d, p, count)  # noqa: E731
    newton = lambda count: lambda t, r, d, p: _newton_chunk(coefficients, r, t, d, p, count)  # noqa: E731
    if initial is not None:  # a refit from an earlier fit: its roots, its branch
        out = map_batches(spline(steps), (target, initial, np.full(len(target), _INITIAL_DAMPING), prior), size, progress, "fitting pixels")
        second, two = initial, np.zeros(len(target), bool)
    else:
        first = lambda t, p: _first_pass_chunk(coefficients, table.device_inverse, t, p, steps)  # noqa: E731
        *out, second, two = map_batches(first, (target, prior), size, progress, "fitting pixels")
    # The fold's second branch, tried only where the inverse table has one and the first branch's
    # shading is far from the reference (the branches' shadings differ by 2-5x) or it fits poorly.
    field = reference is not None and np.ndim(reference) > 0  # a shading per pixel: a smooth field of the image
    if reference is None:
        good = out[1][~two & (out[1] > 0)]
        reference = float(np.median(good)) if good.size else 1.0
    reference = np.broadcast_to(np.asarray(reference, dtype=float), out[1].shape)
    doubtful = np.abs(np.log(np.maximum(out[1], 1e-12) / reference)) > (_DOUBTFUL_FROM_FIELD if field else _DOUBTFUL)
    retry = np.flatnonzero(two & (doubtful | (out[3] > 1e-2)))
    _try_other_start(out, retry, second[retry], spline(steps), target, prior, reference)
    # Where neither start lands near a shading field (in parts of the fold the inverse table's second
    # start leads back to the first branch), a third: the spline's colour nearest the pixel over
    # the field's shading, which lies on the branch that shading selects. Against one shading for
    # all pixels it would pull every pixel of a flat valley (heavy melanin) toward that shading.
    lost = np.flatnonzero(np.abs(np.log(np.maximum(out[1], 1e-12) / reference)) > _LOST) if field else np.empty(0, int)
    if lost.size:
        third = table.starts_for_colours(target[lost] / reference[lost, None])
        _try_other_start(out, lost, third, spline(steps), target, prior, reference)
    roots, shading, remaining, residual, fitted, damping, normal = out

    # a colour this far from the model after the first steps is outside the gamut (hair, cloth,
    # background): it will be OUT_OF_MODEL whatever its last digits, and polishing it would take
    # most of a real photo's time (such colours converge only linearly). Not so under a shading
    # prior (an albedo capture): the start ignores it, and a skin colour whose free-shading fit lies
    # far from the prior's shading starts with a high cost and descends; such a pixel goes on while
    # its cost keeps falling.
    pulled = prior[:, 5] > 0
    moving = np.flatnonzero((remaining > step_tol) & ((residual <= _HOPELESS_RESIDUAL) | pulled))
    rounds = 0
    while moving.size > _TAIL_FROM and rounds < max_rounds:  # gathered, so that converged pixels cost nothing more
        before = residual[moving]
        more = map_batches(newton(straggler_steps), (target[moving], roots[moving], damping[moving], prior[moving]), _SUBSET_CHUNK)
        for full, part in zip(out, more):
            full[moving] = part
        moving = moving[_goes_on(remaining[moving], residual[moving], before, step_tol)]
        rounds += 1
    if moving.size and rounds < max_rounds:
        # the tail (at most one chunk) goes round inside one compiled loop, in a chunk its size:
        # round by round in Python, a few pixels padded to a full chunk cost as much as the chunk
        left = jnp.asarray(max_rounds - rounds)
        tail = lambda t, r, d, p: _straggler_tail(coefficients, r, t, d, p, straggler_steps, left, step_tol)  # noqa: E731
        size = _TAIL_CHUNK if moving.size <= _TAIL_CHUNK else _SUBSET_CHUNK
        *more, still = map_batches(tail, (target[moving], roots[moving], damping[moving], prior[moving]), size)
        for full, part in zip(out, more):
            full[moving] = part
        moving = moving[still]
    moving = moving[residual[moving] <= _HOPELESS_RESIDUAL]
    if moving.size and lm_max_steps:
        lm = lambda t, r, p: _levenberg_marquardt(coefficients, r, t, p, lm_max_steps, 1e-10, 1e-12)  # noqa: E731
        # one chunk size, whatever the count: tracing optimistix's solver costs ~1.7 s a shape
        lm_roots, lm_ok = map_batches(lm, (target[moving], roots[moving], prior[moving]), _LM_CHUNK)
        final = map_batches(spline(0), (target[moving], lm_roots, damping[moving], prior[moving]), _LM_CHUNK)
        for full, part in zip(out, final):
            full[moving] = part
        remaining[moving] = np.where(lm_ok, 0.0, np.inf)
    return out[:5] + [out[6]]


#: |ln(shading / reference)| beyond which a pixel with a second start tries it: against one shading
#: for all pixels, and against a smooth field of the image. Near the fold's edge its branches differ
#: by as little as 1.1-1.3x in shading (both fit exactly), so against a field a coarser threshold
#: leaves a strip on the other branch; against one shading a finer one pulls pixels of a flat valley
#: toward it (noisy copies of one pixel: scatter 0.7x the standard error at 1.05, 0.95x at 1.25).
_DOUBTFUL = np.log(1.25)
_DOUBTFUL_FROM_FIELD = np.log(1.05)
#: Against a field, |ln(shading / field)| beyond which a pixel still that far tries a third start.
_LOST = np.log(1.1)


def _try_other_start(out, index, starts, spline, target, prior, reference):
    """Fit the pixels ``index`` again from ``starts`` (len(index), 2) and keep, per pixel, the fit
    that ``_choose_branch`` prefers (``out``: the solver's outputs, updated in place)."""
    if not index.size:
        return
    damping = np.full(index.size, _INITIAL_DAMPING)
    other = map_batches(spline, (target[index], starts, damping, prior[index]), _SUBSET_CHUNK)
    both = [np.stack([a[index], b]) for a, b in zip(out, other)]  # each (2, len(index), ...)
    choice = _choose_branch(both[1], both[3], reference[index])
    for full, pair in zip(out, both):
        full[index] = pair[choice, np.arange(index.size)]


#: Relative residual (with the prior rows) beyond which a pixel still moving is not polished
#: further (CIEDE2000 is then well above 1); it keeps its status MAX_STEPS or OUT_OF_MODEL.
_HOPELESS_RESIDUAL = 0.03
#: Factor by which a pixel beyond ``_HOPELESS_RESIDUAL`` under a shading prior must lower its cost
#: in a round of straggler steps to go on.
_DESCENDING = 0.9


#: Chunk size for the subsets that go round again (second branch, stragglers): one size, so one
#: compilation whatever the subset's size; small enough that padding wastes little, large enough
#: to keep dispatch overhead negligible.
_SUBSET_CHUNK = 2048


def _choose_branch(shading, residual, reference) -> np.ndarray:
    """Per pixel, the branch (0 or 1) that fits and whose shading is nearest the reference
    (one value or (n,)).

    Inputs (2, n). Branches whose relative residual is within 1 % of the best fit equally well
    (8-bit quantisation alone leaves residuals of 1e-3); among them the shading decides."""
    fits = residual <= residual.min(axis=0) + 1e-2
    distance = np.abs(np.log(np.maximum(shading, 1e-12) / reference))
    return np.argmin(np.where(fits, distance, np.inf), axis=0)
