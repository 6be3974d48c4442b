"""Per-pixel inversion of linear RGB images to melanin, haemoglobin and shading maps.

Camera model: a pixel's linear sRGB (D65 white = 1) is

    rgb = gains * shading * M W R(lambda; C_m, beta_m, C_h)

with R the skin model's diffuse reflectance at 400-700 nm / 10 nm, W the CIE 1931 2-degree colour
matching functions weighted by the illuminant (D65 by default, Bradford-adapted to D65 otherwise),
M the XYZ -> linear sRGB matrix (``skinfit.colorimetry``) and gains the camera's white balance.
Three channels carry three unknowns per pixel: C_m, C_h and the shading; the melanin blend and the
gains are one value for the whole image (given, or fitted once by ``skinfit.calibration``).

``fit_pixels``, per pixel, over fixed-size chunks compiled once:

1. warm start: the inverse table (``skinfit.colour_table``) gives one or two starts from the
   pixel's chromaticity, each refined by a Newton step in chromaticity; the second (a second
   branch of the fold) only where it differs;
2. solve: Levenberg-Marquardt in lock-step on the model's colour spline (exact to ~3e-7 in linear
   sRGB), with the shading eliminated in closed form (variable projection: for a colour m the best
   shading is t.m / m.m), the residual relative to the pixel's brightness so that dark and bright
   pixels weigh alike, the prior on ln C_m and ln C_h as two more residual rows (MAP; weights 0
   without one), and the roots projected onto the box; converged when the undamped Gauss-Newton
   step still to go is at most ``step_tol``. The others are gathered for more steps, and what
   remains goes to optimistix's Levenberg-Marquardt;
3. optionally (``exact_steps``), Gauss-Newton steps on the exact forward model remove the
   spline's last ~1e-7.

Where both branches fit, the one whose shading is nearest a reference wins. ``fit_image`` adds
what one pixel cannot know: the white balance from the skin, the fold's branch chosen against the
smooth shading field of the neighbourhood, an edge-preserving spatial prior, and the statuses of
pixels that are not skin. Pixels that cannot be fitted get a status code and zeros, never NaN.
"""

from __future__ import annotations

import dataclasses
import enum
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ._batching import map_batches, pad_size
from ._validate import SkinfitInputError
from .colorimetry import DEFAULT_ILLUMINANT, delta_e2000, linear_srgb_to_lab, linear_srgb_weights
from .colour_table import (
    COLOUR_WAVELENGTHS_NM,
    HAEMOGLOBIN_MAX,
    MELANIN_MAX,
    ColourTable,
    colour_table,
    model_rgb,
    params_rgb,
    spline_channels,
    spline_rgb,
    warm_starts,
)
from .fit_variables import VARIABLES, prior_coordinate
from .reflectance import model_with_options
from .skin_model import SkinModel, Transport, cache_key, resolve_model


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


def _spline_colour(coefficients):
    """Colour of the spline at roots u, v (n,): (value, d/du, d/dv), each a tuple of 3 channels."""

    def colour(u, v):
        channels = spline_channels(coefficients, u, v)
        return tuple(tuple(channel[i] for channel in channels) for i in range(3))

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


class _Point(NamedTuple):
    """What one iterate carries per pixel (each (n,)): the roots, the cost |r|^2 of the relative
    residual r (shading eliminated), the 2x2 normal equations J^T J (uu, uv, vv) and J^T r
    (gu, gv), the best shading and the model colour (3 channels)."""

    u: jax.Array
    v: jax.Array
    cost: jax.Array
    uu: jax.Array
    uv: jax.Array
    vv: jax.Array
    gu: jax.Array
    gv: jax.Array
    shading: jax.Array
    colour: tuple


def _projected(colour, u, v, target, scale, prior) -> _Point:
    """Variable projection at roots u, v (n,): relative residual r = (t - k m) |t|^-1 with the best
    shading k = t.m / m.m, and the prior's rows (``_prior_rows``), reduced to the normal
    equations of the two roots. Only these ten numbers per pixel travel between steps: carrying r
    and J (13 more) made every kept-or-refused selection recompute the residual."""
    m, dm_u, dm_v = colour(u, v)
    mm = _dot3(m, m)
    tm = _dot3(target, m)
    k = tm / mm

    r = tuple((t - k * c) * scale for t, c in zip(target, m))

    def d_residual(dm):
        dk = _dot3(target, dm) / mm - tm * 2.0 * _dot3(m, dm) / (mm * mm)
        return tuple(-(dk * c + k * d) * scale for c, d in zip(m, dm))

    ju, jv = d_residual(dm_u), d_residual(dm_v)
    cost, uu, uv, vv, gu, gv = _dot3(r, r), _dot3(ju, ju), _dot3(ju, jv), _dot3(jv, jv), _dot3(ju, r), _dot3(jv, r)
    # the prior's rows w (log root - c): d/du = w / u
    centre_u, centre_v, weight_u, weight_v = prior
    row_u, row_v = weight_u * (jnp.log(u) - centre_u), weight_v * (jnp.log(v) - centre_v)
    cost, gu, gv = cost + row_u * row_u + row_v * row_v, gu + weight_u / u * row_u, gv + weight_v / v * row_v
    uu, vv = uu + (weight_u / u) ** 2, vv + (weight_v / v) ** 2
    return _Point(u, v, cost, uu, uv, vv, gu, gv, k, m)


#: Lower bound of the roots in the solver: C = max * root^2 has zero slope at root 0, which would
#: trap a pixel there (the cost is even in the root); 1e-3 means C_m >= 5e-7, C_h >= 1.5e-7.
_ROOT_FLOOR = 1e-3


def _step(point: _Point, damping):
    """The damped Gauss-Newton step (Marquardt's scaling) projected on the box: a root on a bound
    that its step pushes out of the box stays there and the other takes its own one-variable step
    (clipping the joint step instead stalls on the bound)."""
    u, v, _, uu, uv, vv, gu, gv = point[:8]
    floor = 1e-12 * jnp.maximum(uu, vv) + 1e-300  # against a dead direction
    du, dv = uu * (1.0 + damping) + floor, vv * (1.0 + damping) + floor
    det = du * dv - uv * uv
    step_u, step_v = -(dv * gu - uv * gv) / det, -(du * gv - uv * gu) / det
    out_u = ((u <= _ROOT_FLOOR) & (step_u < 0.0)) | ((u >= 1.0) & (step_u > 0.0))
    out_v = ((v <= _ROOT_FLOOR) & (step_v < 0.0)) | ((v >= 1.0) & (step_v > 0.0))
    step_u, step_v = jnp.where(out_v, -gu / du, step_u), jnp.where(out_u, -gv / dv, step_v)
    step_u, step_v = jnp.where(out_u, 0.0, step_u), jnp.where(out_v, 0.0, step_v)
    finite = jnp.isfinite(step_u) & jnp.isfinite(step_v)
    return jnp.where(finite, step_u, 0.0), jnp.where(finite, step_v, 0.0)


def _stationary(point: _Point, tol=1e-4):
    """First-order optimality on the box: each free column of the Jacobian orthogonal to the
    residual to within ``tol`` (cosine); a column at a bound that the gradient pushes out of the
    box counts as orthogonal. At cosine c the step still to go is ~ c |r| / |J|: 1e-4 leaves
    ~1e-6 in the roots for the 1 % residuals of colours just outside the gamut."""
    norm_r = jnp.sqrt(point.cost)

    def free_cosine(g, jj, x):  # g: the cost's half-gradient along this root, jj = |J column|^2
        blocked = ((x <= _ROOT_FLOOR) & (g > 0.0)) | ((x >= 1.0) & (g < 0.0))
        return jnp.where(blocked, 0.0, jnp.abs(g) / (jnp.sqrt(jj) * norm_r + 1e-300))

    return jnp.maximum(free_cosine(point.gu, point.uu, point.u), free_cosine(point.gv, point.vv, point.v)) <= tol


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

    ``prior`` (n, 4): per pixel the centres and weights of the prior rows (``_prior_rows``).

    Returns the roots (n, 2), the shading, ``remaining``, the square root of the cost (relative
    residual and prior rows) (each (n,)), the fitted colour (n, 3), the damping (n,) and the
    Gauss-Newton normal matrix (uu, uv, vv) (n, 3) for standard errors.
    """
    target = (target[:, 0], target[:, 1], target[:, 2])
    scale = 1.0 / jnp.sqrt(_dot3(target, target))
    prior = tuple(prior[:, i] for i in range(4))

    def step(_, state):
        point, damping = state
        step_u, step_v = _step(point, damping)
        trial = _projected(
            colour, jnp.clip(point.u + step_u, _ROOT_FLOOR, 1.0), jnp.clip(point.v + step_v, _ROOT_FLOOR, 1.0), target, scale, prior
        )
        keep = trial.cost <= point.cost
        point = jax.tree.map(lambda new, old: jnp.where(keep, new, old), trial, point)
        return point, jnp.where(keep, jnp.maximum(damping * 0.1, 1e-9), jnp.minimum(damping * 10.0, 1e9))

    start = jnp.clip(roots, _ROOT_FLOOR, 1.0)
    start = _projected(colour, start[:, 0], start[:, 1], target, scale, prior)
    point, damping = jax.lax.fori_loop(0, steps, step, (start, damping))
    step_u, step_v = _step(point, 0.0)
    remaining = jnp.where(_stationary(point), 0.0, jnp.maximum(jnp.abs(step_u), jnp.abs(step_v)))
    fitted = jnp.stack([point.shading * c for c in point.colour], axis=-1)
    normal = jnp.stack([point.uu, point.uv, point.vv], axis=-1)
    return jnp.stack([point.u, point.v], axis=-1), point.shading, remaining, jnp.sqrt(point.cost), fitted, damping, normal


#: Levenberg-Marquardt's first damping: the affine warm starts are close enough that Gauss-Newton
#: rarely overshoots from them; a refused step raises it tenfold.
_INITIAL_DAMPING = 1e-5


@jax.jit
def _spline_chunk(coefficients, roots, target, damping, prior, steps):
    return _gauss_newton(_spline_colour(coefficients), roots, target, damping, steps, prior)


@jax.jit
def _first_pass_chunk(coefficients, inverse, target, prior, steps):
    """Warm starts and ``steps`` steps from the first; also the second start (n, 2) for a retry
    and whether it differs from the first (n,)."""
    starts = warm_starts(inverse, target)
    damping = jnp.full(len(target), _INITIAL_DAMPING, target.dtype)
    solved = _gauss_newton(_spline_colour(coefficients), starts[:, 0], target, damping, steps, prior)
    return (*solved, starts[:, 1], jnp.any(starts[:, 0] != starts[:, 1], axis=-1))


#: Pixels per chunk of the exact transport polish (measured: ~2.2 MB of device memory per pixel).
_TRANSPORT_CHUNK = 1024


@eqx.filter_jit
def _exact_chunk(exact_model, roots, target, prior, steps):
    damping = jnp.full(len(roots), _INITIAL_DAMPING, roots.dtype)
    return _gauss_newton(_exact_colour(*exact_model), roots, target, damping, steps, prior)


@jax.jit
def _delta_e_chunk(measured, fitted):
    return (delta_e2000(linear_srgb_to_lab(measured), linear_srgb_to_lab(fitted)),)


@eqx.filter_jit
def _levenberg_marquardt(coefficients, roots, target, prior, max_steps, rtol, atol):
    """optimistix Levenberg-Marquardt on the spline for the pixels the lock-step solver left
    moving, with the same prior rows; the box by clipping inside the residual (a pixel that ends
    outside sits on the bound its gradient pushes it to)."""

    def residual(z, args):
        t, prior = args
        z = jnp.clip(z, _ROOT_FLOOR, 1.0)
        m = spline_rgb(coefficients, z[None])[0][0]
        k = jnp.dot(t, m) / jnp.dot(m, m)
        return jnp.concatenate([(t - k * m) / jnp.linalg.norm(t), prior[2:] * (jnp.log(z) - prior[:2])])

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
            method (``"transport"``: direct adding-doubling, whose colour table takes minutes on a
            laptop CPU, once per process and blend). The colour spline and the ``exact_steps`` use it.
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
    status, clean = _screen(pixels, mask, black_level, saturation_level)
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
    rows = _prior_rows(model, table, n, prior, colour_noise, prior_mean, prior_sd)
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
            shading_reference, pad_size(todo.size, chunk_size), progress, initial,
        )
        if exact_steps:
            exact_model = table.model_arguments()
            exact = lambda t, r, p: _exact_chunk(exact_model, r, t, p, exact_steps)  # noqa: E731
            # a direct transport Jacobian holds ~2 MB per pixel (doubling loops): smaller chunks
            direct = isinstance(model.method, Transport) and model.method.table is None
            size = pad_size(todo.size, min(chunk_size, _TRANSPORT_CHUNK) if direct else chunk_size)
            polished = map_batches(exact, (clean[todo], solved[0], rows[todo]), size, progress, "exact polish")
            # converged: the spline fit had, and the exact steps leave at most step_tol to go
            polished[2] = np.where(solved[2] <= step_tol, polished[2], np.inf)
            solved = polished[:5] + [polished[6]]
        roots[todo], shading[todo], remaining[todo], _, fitted[todo], normal[todo] = solved
        (delta_e[todo],) = map_batches(_delta_e_chunk, (clean[todo], fitted[todo]), pad_size(todo.size, chunk_size))
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


def _prior_rows(model, table, n, prior, colour_noise, mean, sd) -> np.ndarray:
    """The solver's prior rows (n, 4): centres of ln u, ln v and weights colour_noise / sd(ln u)
    (u = sqrt(C / C_max), so ln u = (ln C - ln C_max) / 2); weights 0 without a prior."""
    population = model.prior
    if prior is None:
        prior = population is not None or mean is not None
    rows = np.zeros((n, 4))
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
    rows[:, 2:] = colour_noise / (sd / 2.0)
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


def _screen(pixels, mask, black_level, saturation_level):
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
    """The spline fit of pixels (n, 3) under the prior rows (n, 4): warm starts (or the roots
    ``initial`` (n, 2)), lock-step steps, the second branch where it may win, stragglers. ``reference``: the shading (one value or per
    pixel) that chooses between the fold's branches (None: the median of single-branch pixels).
    Returns roots, shading, the distance still to go, the root cost, the fitted colour and the
    normal matrix (n, 3)."""
    coefficients = jnp.asarray(table.coefficients)
    spline = lambda count: lambda t, r, d, p: _spline_chunk(coefficients, r, t, d, p, count)  # noqa: E731
    initial_damping = lambda n: np.full(n, _INITIAL_DAMPING)  # noqa: E731
    if initial is not None:  # a refit from an earlier fit: its roots, its branch
        out = map_batches(spline(steps), (target, initial, initial_damping(len(target)), prior), size, progress, "fitting pixels")
        second, two = initial, np.zeros(len(target), bool)
    else:
        first = lambda t, p: _first_pass_chunk(coefficients, table.device_inverse, t, p, steps)  # noqa: E731
        *out, second, two = map_batches(first, (target, prior), size, progress, "fitting pixels")
    # The fold's second branch, tried only where the inverse table has one and the first branch's
    # shading is far from the reference (the branches' shadings differ by 2-5x) or it fits poorly.
    if reference is None:
        good = out[1][~two & (out[1] > 0)]
        reference = float(np.median(good)) if good.size else 1.0
    reference = np.broadcast_to(np.asarray(reference, dtype=float), out[1].shape)
    doubtful = np.abs(np.log(np.maximum(out[1], 1e-12) / reference)) > np.log(1.25)
    retry = np.flatnonzero(two & (doubtful | (out[3] > 1e-2)))
    if retry.size:
        other = map_batches(spline(steps), (target[retry], second[retry], initial_damping(retry.size), prior[retry]), _SUBSET_CHUNK)
        both = [np.stack([a[retry], b]) for a, b in zip(out, other)]  # each (2, len(retry), ...)
        choice = _choose_branch(both[1], both[3], reference[retry])
        for full, pair in zip(out, both):
            full[retry] = pair[choice, np.arange(retry.size)]
    roots, shading, remaining, residual, fitted, damping, normal = out

    # a colour this far from the model after the first steps is outside the gamut (hair, cloth,
    # background): it will be OUT_OF_MODEL whatever its last digits, and polishing it would take
    # most of a real photo's time (such colours converge only linearly)
    moving = np.flatnonzero((remaining > step_tol) & (residual <= _HOPELESS_RESIDUAL))
    for _ in range(max_rounds):  # gathered, so that converged pixels cost nothing more
        if not moving.size:
            break
        more = map_batches(spline(straggler_steps), (target[moving], roots[moving], damping[moving], prior[moving]), _SUBSET_CHUNK)
        for full, part in zip(out, more):
            full[moving] = part
        moving = moving[remaining[moving] > step_tol]
    moving = moving[residual[moving] <= _HOPELESS_RESIDUAL]
    if moving.size and lm_max_steps:
        lm = lambda t, r, p: _levenberg_marquardt(coefficients, r, t, p, lm_max_steps, 1e-10, 1e-12)  # noqa: E731
        lm_roots, lm_ok = map_batches(lm, (target[moving], roots[moving], prior[moving]), pad_size(moving.size, 256))
        final = map_batches(spline(0), (target[moving], lm_roots, damping[moving], prior[moving]), pad_size(moving.size, 256))
        for full, part in zip(out, final):
            full[moving] = part
        remaining[moving] = np.where(lm_ok, 0.0, np.inf)
    return out[:5] + [out[6]]


#: Relative residual (with the prior rows) beyond which a pixel still moving is not polished
#: further (CIEDE2000 is then well above 1); it keeps its status MAX_STEPS or OUT_OF_MODEL.
_HOPELESS_RESIDUAL = 0.03


#: Chunk size for the subsets that go round again (second branch, stragglers): one size, so one
#: compilation whatever the subset's size; small enough that padding wastes little, large enough
#: to keep dispatch overhead negligible.
_SUBSET_CHUNK = 2048


def _choose_branch(shading, residual, reference) -> np.ndarray:
    """Per pixel, the branch (0 or 1) that fits and whose shading is nearest the reference
    (one value or (n,)).

    Inputs (2, n). Branches whose relative residual is within 1 % of the best fit equally well
    (8-bit quantisation alone leaves residuals of 1e-3); among them the shading decides.
    """
    fits = residual <= residual.min(axis=0) + 1e-2
    distance = np.abs(np.log(np.maximum(shading, 1e-12) / reference))
    return np.argmin(np.where(fits, distance, np.inf), axis=0)


@dataclasses.dataclass(frozen=True)
class ImageFit:
    """Parameter maps of one image (each (h, w)), its reconstruction and a summary.

    ``status`` holds ``PixelStatus`` codes; pixels that were not fitted hold 0 in every map. Maps
    are float32 (relative precision 6e-8, as the EXR stores them).
    ``white_balance`` are the camera gains (r, g, b) the fit divided out (1 unless fitted), and
    ``colour_chart`` the chart correction applied first (or None): ``fitted_linear_rgb`` is in the
    camera's values, as the input.
    """

    melanin: np.ndarray
    melanin_blend: np.ndarray
    haemoglobin: np.ndarray
    shading: np.ndarray
    residual_dE2000: np.ndarray
    status: np.ndarray
    fitted_linear_rgb: np.ndarray  # (h, w, 3)
    seconds: float
    melanin_se: np.ndarray | None = None
    haemoglobin_se: np.ndarray | None = None
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    model: SkinModel | None = None
    colour_chart: object | None = None  # the ChartCalibration the image was corrected with

    @property
    def model_name(self) -> str:
        return resolve_model(self.model).name

    @property
    def skin_mask(self) -> np.ndarray:
        """The automatic skin mask (h, w) bool: pixels fitted as skin (``SUCCESS``): not masked,
        in the model's gamut, with parameters skin has, no glint."""
        return self.status == PixelStatus.SUCCESS

    MAP_NAMES = ("melanin", "melanin_blend", "haemoglobin", "shading", "residual_dE2000", "status", "melanin_se", "haemoglobin_se")

    def maps(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in self.MAP_NAMES if getattr(self, name) is not None}

    def render(self, scale_melanin: float = 1.0, scale_haemoglobin: float = 1.0, illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
        """Linear sRGB (h, w, 3) of the maps with scaled melanin and haemoglobin (an edit), through
        the exact model and the fitted white balance. Pixels with maps (status up to
        ``OUT_OF_MODEL``) are rendered; the others keep their fitted colour (0)."""
        edited = render_maps(
            scale_melanin * self.melanin, scale_haemoglobin * self.haemoglobin, self.shading,
            melanin_blend=self.melanin_blend, illuminant=illuminant, model=self.model,
        ) * np.asarray(self.white_balance)
        if self.colour_chart is not None:
            edited = self.colour_chart.invert(edited)
        return np.where((self.status <= PixelStatus.OUT_OF_MODEL)[..., None], edited, self.fitted_linear_rgb)

    def summary(self) -> dict[str, float]:
        """Pixels, fitted fraction, median and 95th-percentile CIEDE2000 of the fitted pixels,
        the blend and white balance, time."""
        fitted = self.status == PixelStatus.SUCCESS
        delta_e = self.residual_dE2000[fitted]
        return {
            "pixels": int(self.status.size),
            "fitted": int(fitted.sum()),
            "fitted_fraction": float(fitted.mean()),
            "median_dE2000": float(np.median(delta_e)) if delta_e.size else float("nan"),
            "p95_dE2000": float(np.percentile(delta_e, 95)) if delta_e.size else float("nan"),
            # the blend of the fitted pixels (the map holds 0 where nothing was fitted)
            "melanin_blend": round(float(np.median(self.melanin_blend[fitted])), 6) if fitted.any() else float("nan"),
            "white_balance": list(self.white_balance),
            **({"colour_chart_matrix": self.colour_chart.matrix.tolist(),
                "colour_chart_median_dE2000": float(np.median(self.colour_chart.delta_e2000))} if self.colour_chart is not None else {}),
            "model": self.model_name,
            "seconds": self.seconds,
        }


#: Spatial regularisation of ln C_m and ln C_h (``fit_image(regularisation=...)``): the standard
#: deviation of a pixel's value about the median of its neighbourhood, and that neighbourhood's size.
REGULARISATION = {"off": None, "light": (0.3, 3), "strong": (0.05, 5)}


def fit_image(
    image,
    *,
    melanin_blend: float | None = None,
    fit_blend: bool = False,
    white_balance: str | bool | tuple[float, float, float] = "auto",
    input_space: str | None = None,
    mask=None,
    use_alpha: bool = True,
    illuminant: str = DEFAULT_ILLUMINANT,
    regularisation: str = "light",
    colour_chart=False,
    method: str | None = None,
    model: SkinModel | None = None,
    progress: bool | None = None,
    **options,
) -> ImageFit:
    """Fit melanin, haemoglobin and shading maps to a photo or albedo image.

    Args:
        image: a path (read through OpenImageIO, see ``skinfit.images``) or a linear sRGB array
            (h, w, 3).
        melanin_blend: beta_m for the whole image (three channels cannot carry it per pixel);
            default: the population mean of the model's prior (0.42 for the calibrated model),
            0.7 without a prior (DJ2006).
        fit_blend: fit beta_m once for the whole image instead (``skinfit.calibration``).
        white_balance: ``"auto"`` (default) fits per-channel camera gains once for the image from
            its skin pixels (``skinfit.calibration``: photos and captures of unknown balance);
            ``"none"`` for inputs known to be calibrated (albedo in linear sRGB, D65 white = 1);
            a tuple (r, g, b) gives them. ``True``/``False`` mean ``"auto"``/``"none"``.
        input_space: encoding of a file (``None``: from its type and metadata).
        mask: (h, w) array or image path; pixels where it is 0 are not fitted (status MASKED).
        use_alpha: treat the file's alpha channel as a mask.
        illuminant: the illuminant of the camera model (colour-science name; D65 default).
        regularisation: ``"off"``, ``"light"`` (default) or ``"strong"``: a prior on each pixel's
            ln C_m and ln C_h centred on the median of its neighbourhood (edge-preserving), of
            standard deviation 0.3 / 0.05 over 3 x 3 / 5 x 5 pixels, combined with the population prior
            (weighed against the colour by ``colour_noise``: at 1 % noise light keeps ~95 % of a pixel's own
            value, strong ~30 %);
            ``prior=False`` (maximum likelihood) turns it off as well.
        colour_chart: ``True`` finds a ColorChecker in the frame and fits the image in the colours
            its correction matrix gives (``skinfit.colour_chart``; the white balance is then
            ``"none"`` unless given); or a ``ChartCalibration`` from another shot of the same setup.
            Reconstructions and renders go back through the matrix to the camera's values.
        model: the ``SkinModel`` (default: the package default); ``method`` overrides its forward
            method as in ``fit_pixels``.
        **options: passed to ``fit_pixels`` (prior, colour_noise, max_delta_e, chunk_size, ...).

    Spatial coherence: the fold's branches differ in shading by 2-5x, and shading varies smoothly
    over a face, so after a first pass the branch of every pixel whose shading is far from the
    smooth shading field of its surroundings is chosen again against that field (unless
    ``shading_reference`` is given).
    """
    import time

    from .images import read_linear_rgb, read_mask

    start = time.perf_counter()
    model = model_with_options(model, method=method)
    if regularisation not in REGULARISATION:
        raise SkinfitInputError(f"regularisation must be one of {', '.join(REGULARISATION)}, got {regularisation!r}")
    alpha = None
    if _is_path(image):
        rgb, alpha = read_linear_rgb(image, input_space)
        rgb = rgb.astype(np.float32)  # a file holds no more (float, half or integer): half the memory of a 4096^2 image
    else:
        rgb = np.asarray(image, dtype=float)
        if rgb.ndim != 3 or rgb.shape[-1] != 3:
            raise SkinfitInputError(f"expected an image of shape (h, w, 3), got {rgb.shape}")
    if _is_path(mask):
        mask = read_mask(mask)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.ndim == 3 and mask.shape[-1] == 1:
            mask = mask[..., 0]
        if mask.shape != rgb.shape[:2]:
            raise SkinfitInputError(f"mask has shape {mask.shape}, the image {rgb.shape[:2]}")
    if use_alpha and alpha is not None:
        mask = alpha if mask is None else np.minimum(mask, alpha)
    chart = None
    if colour_chart is not False and colour_chart is not None:
        from .colour_chart import ChartCalibration, chart_calibration

        chart = colour_chart if isinstance(colour_chart, ChartCalibration) else chart_calibration(rgb)
        rgb = chart.apply(rgb)
        if isinstance(white_balance, str) and white_balance == "auto":
            white_balance = "none"
    if melanin_blend is None:
        melanin_blend = _population_blend(model)
    if isinstance(white_balance, bool):
        white_balance = "auto" if white_balance else "none"
    gains = np.ones(3)
    if fit_blend or (isinstance(white_balance, str) and white_balance == "auto"):
        from .calibration import calibrate

        pixels = rgb.reshape(-1, 3)
        screened, _ = _screen(pixels, mask, options.get("black_level", 1e-4), options.get("saturation_level", 0.999))
        fittable = screened == PixelStatus.SUCCESS
        if not fittable.any():
            raise SkinfitInputError("no pixel of the image can be fitted (all black, saturated, masked or invalid)")
        calibration = calibrate(
            pixels[fittable], melanin_blend=None if fit_blend else melanin_blend, white_balance=white_balance == "auto",
            illuminant=illuminant, model=model, colour_noise=options.get("colour_noise", 0.003), prior=options.get("prior"),
        )
        melanin_blend, gains = calibration.melanin_blend, np.asarray(calibration.white_balance)
    elif isinstance(white_balance, str):
        if white_balance != "none":
            raise SkinfitInputError(f"white_balance must be 'auto', 'none' or three positive gains, got {white_balance!r}")
    else:
        gains = np.asarray(white_balance, dtype=float)
        if gains.shape != (3,) or not np.all(gains > 0):
            raise SkinfitInputError(f"white_balance must be 'auto', 'none' or three positive gains, got {white_balance}")
    options = dict(melanin_blend=melanin_blend, illuminant=illuminant, model=model, **options)
    maps = _fit_in_bands(rgb, gains, mask, options, progress)
    if options.get("shading_reference") is None:
        field = _coherent_branches(rgb, gains, maps, options)
    else:
        field = np.broadcast_to(np.asarray(options["shading_reference"], dtype=float), rgb.shape[:2])
    if REGULARISATION[regularisation] is not None and options.get("prior") is not False:
        _regularise(rgb, gains, maps, field, options, *REGULARISATION[regularisation])
    _classify(rgb, gains, maps, field, model)
    fitted = maps.pop("fitted_rgb")
    if chart is not None:
        fitted = chart.invert(fitted).astype(fitted.dtype)
    return ImageFit(**maps, fitted_linear_rgb=fitted, seconds=time.perf_counter() - start, white_balance=tuple(float(g) for g in gains),
                    model=model, colour_chart=chart)


def _population_blend(model: SkinModel) -> float:
    """The blend a fit uses when none is given: the population prior's mean, else DJ2006's 0.7."""
    prior = model.prior
    if prior is None or "melanin_blend" not in prior.names:
        return 0.7
    logit, _ = prior.moments("melanin_blend")
    var = VARIABLES["melanin_blend"]
    return round(var.low + (var.high - var.low) / (1.0 + np.exp(-logit)), 3)


#: Shading ratio to the smooth field beyond which a pixel's branch is chosen again.
_FAR_FROM_FIELD = np.log(1.25)


def _fitted(maps) -> np.ndarray:
    return (maps["status"] == PixelStatus.SUCCESS) | (maps["status"] == PixelStatus.MAX_STEPS)


def _field_sigma(shape) -> float:
    """Smoothing scale of the shading field: 1 % of the image's larger side, at least 2 pixels."""
    return max(2.0, 0.01 * max(shape))


def _shading_field(maps) -> np.ndarray:
    """Smooth ln-shading field of the fitted pixels, twice: the second leaves out pixels far from
    the first (those on the other branch)."""
    from ._spatial import smooth_field

    fitted = _fitted(maps)
    log_k = np.log(np.maximum(maps["shading"], np.float32(1e-12)))  # float32, as the maps
    sigma = _field_sigma(log_k.shape)
    field = smooth_field(log_k, fitted, sigma)
    near = fitted & (np.abs(log_k - field) <= _FAR_FROM_FIELD)
    return smooth_field(log_k, near, sigma)


def _refit(rgb, gains, maps, where, options, band_pixels: int = 1 << 18, **overrides):
    """Fit again the pixels ``where`` (h, w) with ``overrides`` (per-pixel arrays (h, w, ...) are
    taken at those pixels) and write the results into ``maps``, ``band_pixels`` at a time (the
    working memory of a 4096 x 4096 image stays that of one band)."""
    rows, cols = np.nonzero(where)
    for start in range(0, rows.size, band_pixels):
        index = rows[start : start + band_pixels], cols[start : start + band_pixels]
        pick = lambda v: v[index] if isinstance(v, np.ndarray) and v.ndim >= 2 else v  # noqa: E731
        extra = {k: tuple(pick(a) for a in v) if isinstance(v, tuple) else pick(v) for k, v in overrides.items()}
        part = fit_pixels(rgb[index], white_balance=tuple(gains), progress=False, **dict(options, **extra))
        part["fitted_rgb"] = part["fitted_rgb"] * gains
        for k, v in part.items():
            maps[k][index] = v


def _coherent_branches(rgb, gains, maps, options) -> np.ndarray:
    """Choose the fold's branch again against the local shading field where the first pass's
    shading is far from it; returns the field (h, w) (linear shading)."""
    field = np.exp(_shading_field(maps))
    # out-of-model pixels (hair, background) have no branch worth choosing, and are the slowest to refit
    far = _fitted(maps) & (np.abs(np.log(np.maximum(maps["shading"], np.float32(1e-12)) / field)) > _FAR_FROM_FIELD)
    _refit(rgb, gains, maps, far, options, shading_reference=field)
    return field


def _regularise(rgb, gains, maps, field, options, sd, size):
    """Refit every fitted pixel under a prior centred on its neighbourhood's median ln C (an
    edge-preserving centre), combined with the population prior (precisions add)."""
    from ._spatial import neighbourhood_median, smooth_field

    fitted = _fitted(maps)
    if not fitted.any():
        return
    model = options["model"]
    centres, sds = [], []
    population = model.prior
    for name in ("melanin", "haemoglobin"):
        log_c = np.log(np.maximum(maps[name], np.float32(1e-9)))
        fill = smooth_field(log_c, fitted, _field_sigma(log_c.shape))
        centre = neighbourhood_median(log_c, fitted, size, fill)
        if population is not None and options.get("prior", True) is not False:
            p_mean, p_sd = population.moments(name)
            precision = 1.0 / sd**2 + 1.0 / p_sd**2
            centre, combined = (centre / sd**2 + p_mean / p_sd**2) / precision, np.sqrt(1.0 / precision)
        else:
            combined = sd
        centres.append(centre.astype(np.float32))  # float32: a 4096 x 4096 image's centres in 134 MB
        sds.append(combined)
    _refit(rgb, gains, maps, fitted, options, prior_mean=np.stack(centres, axis=-1), prior_sd=np.array(sds),
           shading_reference=field, prior=True, initial=(maps["melanin"], maps["haemoglobin"]))


#: Candidate pixels per chunk of the glint test.
_CLASSIFY_CHUNK = 1 << 18

#: Relative residual below which a pixel is the neighbourhood's skin colour plus white (a glint).
_SPECULAR_FIT = 0.03

#: |ln(shading / shading field)| beyond which a pixel is another surface than the skin around it
#: (a factor 3: the fold's branches differ by 2-5x, but the field has chosen among them already).
_OTHER_SURFACE = np.log(3.0)

#: Population-prior standard deviations of ln C beyond which a fit is not skin (5: C_m outside
#: 0.5-85 %, C_h outside 0.08-62 % for the calibrated model's prior).
_IMPLAUSIBLE_Z = 5.0


def _classify(rgb, gains, maps, field, model):
    """Statuses of pixels that fit the model badly or implausibly: ``SPECULAR`` (the smooth local
    skin colour at no less than 80 % of the local shading plus a white component of at least 10 %
    of the pixel), ``NOT_SKIN`` (roots pinned at the box's far edge, ln C more than
    ``_IMPLAUSIBLE_Z`` prior standard deviations from the population mean, or a shading 3x off the
    smooth field of its surroundings: hair, brows, eyes).
    Their maps are zeroed: a value no skin has is never presented as skin."""
    from ._spatial import smooth_field

    status = maps["status"]
    pinned = (maps["melanin"] >= 0.999 * MELANIN_MAX) | (maps["haemoglobin"] >= 0.999 * HAEMOGLOBIN_MAX)
    implausible = pinned
    population = model.prior
    if population is not None:
        for name in ("melanin", "haemoglobin"):
            mean, sd = population.moments(name)
            implausible = implausible | (np.abs(prior_coordinate(name, maps[name]) - mean) > _IMPLAUSIBLE_Z * sd)
    # another surface than the skin around it (hair, brows, eyes): a shading far from the field
    implausible = implausible | (np.abs(np.log(np.maximum(maps["shading"], 1e-12) / field)) > _OTHER_SURFACE)
    status[(status <= PixelStatus.OUT_OF_MODEL) & implausible] = PixelStatus.NOT_SKIN

    # glints: t = a L + s g, with L the local skin colour per unit shading and g the white (gains)
    candidates = np.nonzero((status == PixelStatus.OUT_OF_MODEL) | (status == PixelStatus.NOT_SKIN))
    skin = status == PixelStatus.SUCCESS
    if candidates[0].size and skin.any():
        sigma = _field_sigma(status.shape)
        fields = [smooth_field(maps["fitted_rgb"][..., c] / np.maximum(maps["shading"], np.float32(1e-12)), skin, sigma) for c in range(3)]
        for start in range(0, candidates[0].size, _CLASSIFY_CHUNK):  # bounded temporaries on a 4096^2 image
            index = tuple(i[start : start + _CLASSIFY_CHUNK] for i in candidates)
            local = np.stack([f[index] for f in fields], axis=-1)
            t = rgb[index]
            basis = np.stack([local, np.broadcast_to(gains, local.shape)], axis=-1)  # (n, 3, 2)
            # normal equations of the two columns, batched (1e-30: a black local colour)
            gram = np.einsum("nck,ncl->nkl", basis, basis) + 1e-30 * np.eye(2)
            coef = np.linalg.solve(gram, np.einsum("nck,nc->nk", basis, t)[..., None])[..., 0]
            residual = np.linalg.norm(t - np.einsum("nck,nk->nc", basis, coef), axis=-1) / np.maximum(np.linalg.norm(t, axis=-1), 1e-12)
            white_share = coef[:, 1] * np.mean(gains) / np.maximum(np.mean(t, axis=-1), 1e-12)
            glint = (coef[:, 0] > 0.8 * field[index]) & (white_share > 0.1) & (residual < _SPECULAR_FIT)
            status[tuple(i[glint] for i in index)] = PixelStatus.SPECULAR
    not_skin = status >= PixelStatus.NOT_SKIN
    for name in ("melanin", "haemoglobin", "shading", "melanin_se", "haemoglobin_se"):
        maps[name][not_skin] = 0.0


def _fit_in_bands(rgb, gains, mask, options, progress, band_pixels: int = 1 << 18):
    """``fit_pixels`` over bands of rows of at most ``band_pixels`` pixels, into preallocated
    float32 maps (as the EXR stores them; ``fit_pixels`` returns float64): the working memory of a
    4096 x 4096 image stays that of one band. The shading reference that picks the fold's branch
    comes from the first band."""
    h, w, _ = rgb.shape
    rows = max(1, band_pixels // max(w, 1))
    maps = None
    bands = range(0, h, rows)
    if progress is None:
        progress = len(bands) > 1
    if progress and len(bands) > 1:
        from tqdm.auto import tqdm

        bands = tqdm(bands, desc="fitting bands", unit="band")
    for top in bands:
        # the camera's values: black and clipped pixels are judged before the white balance divides them
        part = fit_pixels(rgb[top : top + rows], mask=None if mask is None else mask[top : top + rows], white_balance=tuple(gains),
                          progress=False, **options)
        part["fitted_rgb"] = part["fitted_rgb"] * gains
        if maps is None:
            maps = {k: np.zeros((h, w, *v.shape[2:]), np.float32 if v.dtype == np.float64 else v.dtype) for k, v in part.items()}
            if options.get("shading_reference") is None and len(range(0, h, rows)) > 1:
                fitted = part["status"] == PixelStatus.SUCCESS
                options = dict(options, shading_reference=float(np.median(part["shading"][fitted])) if fitted.any() else None)
        for k, v in part.items():
            maps[k][top : top + rows] = v
    return maps


def _is_path(value) -> bool:
    return isinstance(value, (str, bytes)) or hasattr(value, "__fspath__")


def render_maps(
    melanin,
    haemoglobin,
    shading,
    *,
    melanin_blend=0.7,
    illuminant: str = DEFAULT_ILLUMINANT,
    chunk_size: int = 65536,
    method: str | None = None,
    model: SkinModel | None = None,
) -> np.ndarray:
    """Linear sRGB (h, w, 3) of parameter maps through the exact forward model and camera model.

    Maps (h, w) in physical units (volume fractions; the blend may be a map or one value) are
    clipped to [0, 1]; pixels go through in fixed-size chunks, so memory stays bounded.
    """
    melanin, haemoglobin, shading = (np.asarray(a, dtype=float) for a in (melanin, haemoglobin, shading))
    blend = np.broadcast_to(np.asarray(melanin_blend, dtype=float), melanin.shape)
    columns = np.stack([np.clip(a, 0.0, 1.0).ravel() for a in (melanin, blend, haemoglobin)], axis=-1)
    weights = jnp.asarray(linear_srgb_weights(COLOUR_WAVELENGTHS_NM, illuminant))
    model = model_with_options(model, method=method)
    (rgb,) = map_batches(
        lambda c: (params_rgb(c, weights, model),), (columns,), pad_size(len(columns), chunk_size)
    )
    return shading[..., None] * rgb.reshape(*melanin.shape, 3)

