"""Per-pixel inversion of linear RGB images to melanin, haemoglobin and shading maps.

Camera model: a pixel's linear sRGB (D65 white = 1) is

    rgb = shading * M W R(lambda; C_m, beta_m, C_h)

with R the DJ2006 diffuse reflectance at 400-700 nm / 10 nm, W the CIE 1931 2-degree colour
matching functions weighted by the illuminant (D65 by default, Bradford-adapted to D65 otherwise)
and M the XYZ -> linear sRGB matrix (``skinfit.colorimetry``). Three channels carry three unknowns
per pixel: C_m, C_h and the shading; the melanin blend is one value for the whole image (given, or
chosen once by ``skinfit.calibration``).

Per pixel, over fixed-size chunks compiled once:

1. warm start: the inverse table (``skinfit.colour_table``) gives one or two starts from the
   pixel's chromaticity, each refined by a Newton step in chromaticity; the second (a second
   branch of the fold) only where it differs;
2. solve: Levenberg-Marquardt in lock-step on the model's colour spline (exact to ~3e-7 in linear sRGB),
   with the shading eliminated in closed form (variable projection: for a colour m the best
   shading is t.m / m.m), the residual relative to the pixel's brightness so that dark and bright
   pixels weigh alike, and the roots projected onto the box; converged when the undamped
   Gauss-Newton step still to go is at most ``step_tol``. The others are gathered for more steps,
   and what remains goes to optimistix's Levenberg-Marquardt;
3. optionally (``exact_steps``), Gauss-Newton steps on the exact forward model remove the
   spline's last ~1e-7.

Where both branches fit, the one whose shading is nearest the image's typical shading wins.
Pixels that cannot be fitted get a status code and zeros, never NaN.
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
    ColourTable,
    colour_table,
    model_rgb,
    params_rgb,
    spline_channels,
    spline_rgb,
    warm_starts,
)
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


def _projected(colour, u, v, target, scale) -> _Point:
    """Variable projection at roots u, v (n,): relative residual r = (t - k m) |t|^-1 with the best
    shading k = t.m / m.m, reduced to the normal equations of the two roots. Only these ten numbers
    per pixel travel between steps: carrying r and J (13 more) made every kept-or-refused
    selection recompute the residual."""
    m, dm_u, dm_v = colour(u, v)
    mm = _dot3(m, m)
    tm = _dot3(target, m)
    k = tm / mm
    r = tuple((t - k * c) * scale for t, c in zip(target, m))

    def d_residual(dm):
        dk = _dot3(target, dm) / mm - tm * 2.0 * _dot3(m, dm) / (mm * mm)
        return tuple(-(dk * c + k * d) * scale for c, d in zip(m, dm))

    ju, jv = d_residual(dm_u), d_residual(dm_v)
    return _Point(u, v, _dot3(r, r), _dot3(ju, ju), _dot3(ju, jv), _dot3(jv, jv), _dot3(ju, r), _dot3(jv, r), k, m)


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


def _gauss_newton(colour, roots, target, damping, steps):
    """``steps`` Levenberg-Marquardt steps in lock-step over pixels (n, 3) from roots (n, 2) with
    the damping (n,) they start with (a straggler goes on with the damping it stopped at).

    Each step solves the 2x2 damped normal equations, projects the step onto the box and keeps it
    only if the cost does not rise; the damping falls after a kept step and rises after a refused
    one (under heavy melanin the haemoglobin direction is weak and undamped Gauss-Newton
    overshoots). ``remaining`` estimates each pixel's distance to the optimum in the roots: the
    undamped step from the final point (Gauss-Newton converges quadratically, so after it the
    error would be ~its square), or 0 where the point is first-order stationary (colours outside
    the gamut, where the steps shrink only linearly).

    Returns the roots (n, 2), the shading, ``remaining``, the relative residual (each (n,)), the
    fitted colour (n, 3) and the damping (n,).
    """
    target = (target[:, 0], target[:, 1], target[:, 2])
    scale = 1.0 / jnp.sqrt(_dot3(target, target))

    def step(_, state):
        point, damping = state
        step_u, step_v = _step(point, damping)
        trial = _projected(
            colour, jnp.clip(point.u + step_u, _ROOT_FLOOR, 1.0), jnp.clip(point.v + step_v, _ROOT_FLOOR, 1.0), target, scale
        )
        keep = trial.cost <= point.cost
        point = jax.tree.map(lambda new, old: jnp.where(keep, new, old), trial, point)
        return point, jnp.where(keep, jnp.maximum(damping * 0.1, 1e-9), jnp.minimum(damping * 10.0, 1e9))

    start = jnp.clip(roots, _ROOT_FLOOR, 1.0)
    start = _projected(colour, start[:, 0], start[:, 1], target, scale)
    point, damping = jax.lax.fori_loop(0, steps, step, (start, damping))
    step_u, step_v = _step(point, 0.0)
    remaining = jnp.where(_stationary(point), 0.0, jnp.maximum(jnp.abs(step_u), jnp.abs(step_v)))
    fitted = jnp.stack([point.shading * c for c in point.colour], axis=-1)
    return jnp.stack([point.u, point.v], axis=-1), point.shading, remaining, jnp.sqrt(point.cost), fitted, damping


#: Levenberg-Marquardt's first damping: the affine warm starts are close enough that Gauss-Newton
#: rarely overshoots from them; a refused step raises it tenfold.
_INITIAL_DAMPING = 1e-5


@jax.jit
def _spline_chunk(coefficients, roots, target, damping, steps):
    return _gauss_newton(_spline_colour(coefficients), roots, target, damping, steps)


@jax.jit
def _first_pass_chunk(coefficients, inverse, target, steps):
    """Warm starts and ``steps`` steps from the first; also the second start (n, 2) for a retry
    and whether it differs from the first (n,)."""
    starts = warm_starts(inverse, target)
    damping = jnp.full(len(target), _INITIAL_DAMPING, target.dtype)
    solved = _gauss_newton(_spline_colour(coefficients), starts[:, 0], target, damping, steps)
    return (*solved, starts[:, 1], jnp.any(starts[:, 0] != starts[:, 1], axis=-1))


#: Pixels per chunk of the exact transport polish (measured: ~2.2 MB of device memory per pixel).
_TRANSPORT_CHUNK = 1024


@eqx.filter_jit
def _exact_chunk(exact_model, roots, target, steps):
    return _gauss_newton(_exact_colour(*exact_model), roots, target, jnp.full(len(roots), _INITIAL_DAMPING, roots.dtype), steps)


@jax.jit
def _delta_e_chunk(measured, fitted):
    return (delta_e2000(linear_srgb_to_lab(measured), linear_srgb_to_lab(fitted)),)


@eqx.filter_jit
def _levenberg_marquardt(coefficients, roots, target, max_steps, rtol, atol):
    """optimistix Levenberg-Marquardt on the spline for the pixels the lock-step solver left
    moving; the box by clipping inside the residual (a pixel that ends outside sits on the bound
    its gradient pushes it to)."""

    def residual(z, t):
        m = spline_rgb(coefficients, jnp.clip(z, 0.0, 1.0)[None])[0][0]
        k = jnp.dot(t, m) / jnp.dot(m, m)
        return (t - k * m) / jnp.linalg.norm(t)

    def one(r0, t):
        solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
        sol = optx.least_squares(residual, solver, r0, args=t, max_steps=max_steps, throw=False)
        z = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, r0)
        return jnp.clip(z, 0.0, 1.0), sol.result == optx.RESULTS.successful

    return jax.vmap(one)(roots, target)


def fit_pixels(
    linear_rgb: np.ndarray,
    *,
    melanin_blend: float = 0.7,
    illuminant: str = DEFAULT_ILLUMINANT,
    mask: np.ndarray | None = None,
    steps: int = 1,
    straggler_steps: int = 2,
    max_straggler_rounds: int = 16,
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

    Returns maps of the input's leading shape: ``melanin``, ``melanin_blend``, ``haemoglobin``,
    ``shading``, ``residual_dE2000``, ``status`` (``PixelStatus``) and ``fitted_rgb`` (..., 3).
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
    roots, shading, remaining, delta_e, fitted = np.zeros((n, 2)), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros((n, 3))
    if todo.size:
        solved = _solve(
            table, clean[todo], steps, straggler_steps, max_straggler_rounds, lm_max_steps, step_tol,
            shading_reference, pad_size(todo.size, chunk_size), progress,
        )
        if exact_steps:
            exact_model = table.model_arguments()
            exact = lambda t, r: _exact_chunk(exact_model, r, t, exact_steps)  # noqa: E731
            # a direct transport Jacobian holds ~2 MB per pixel (doubling loops): smaller chunks
            direct = isinstance(model.method, Transport) and model.method.table is None
            size = pad_size(todo.size, min(chunk_size, _TRANSPORT_CHUNK) if direct else chunk_size)
            polished = map_batches(exact, (clean[todo], solved[0]), size, progress, "exact polish")[:5]
            # converged: the spline fit had, and the exact steps leave at most step_tol to go
            polished[2] = np.where(solved[2] <= step_tol, polished[2], np.inf)
            solved = polished
        roots[todo], shading[todo], remaining[todo], _, fitted[todo] = solved
        (delta_e[todo],) = map_batches(_delta_e_chunk, (clean[todo], fitted[todo]), pad_size(todo.size, chunk_size))
        status[todo[remaining[todo] > step_tol]] = PixelStatus.MAX_STEPS
        # a colour the model misses by more than max_delta_e is not skin as the camera model sees
        # it, whether or not the solver settled (colours far outside the gamut settle slowly)
        status[todo[delta_e[todo] > max_delta_e]] = PixelStatus.OUT_OF_MODEL
    fitted_any = np.isin(status, (PixelStatus.SUCCESS, PixelStatus.MAX_STEPS, PixelStatus.OUT_OF_MODEL))
    melanin, haemoglobin = table.parameters(roots)
    maps = {
        "melanin": melanin,
        "melanin_blend": np.full(n, float(melanin_blend)),
        "haemoglobin": haemoglobin,
        "shading": shading,
        "residual_dE2000": delta_e,
    }
    for values in maps.values():
        values[~fitted_any] = 0.0
    fitted[~fitted_any] = 0.0
    maps["status"] = status
    maps["fitted_rgb"] = fitted
    return {k: v.reshape(*shape, *v.shape[1:]) for k, v in maps.items()}


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


def _solve(table, target, steps, straggler_steps, max_rounds, lm_max_steps, step_tol, reference, size, progress):
    """The spline fit of pixels (n, 3): warm starts, lock-step steps, the second branch where it may
    win, stragglers. Returns roots, shading, the distance still to go, relative residual and fitted
    colour."""
    coefficients = jnp.asarray(table.coefficients)
    spline = lambda count: lambda t, r, d: _spline_chunk(coefficients, r, t, d, count)  # noqa: E731
    initial = lambda n: np.full(n, _INITIAL_DAMPING)  # noqa: E731
    first = lambda t: _first_pass_chunk(coefficients, table.device_inverse, t, steps)  # noqa: E731
    *out, second, two = map_batches(first, (target,), size, progress, "fitting pixels")
    # The fold's second branch, tried only where the inverse table has one and the first branch's
    # shading is far from the image's typical shading (the branches' shadings differ by 2-5x).
    if reference is None:
        good = out[1][~two & (out[1] > 0)]
        reference = float(np.median(good)) if good.size else 1.0
    doubtful = np.abs(np.log(np.maximum(out[1], 1e-12) / reference)) > np.log(1.25)
    retry = np.flatnonzero(two & (doubtful | (out[3] > 1e-2)))
    if retry.size:
        other = map_batches(spline(steps), (target[retry], second[retry], initial(retry.size)), _SUBSET_CHUNK)
        both = [np.stack([a[retry], b]) for a, b in zip(out, other)]  # each (2, len(retry), ...)
        choice = _choose_branch(both[1], both[3], reference)
        for full, pair in zip(out, both):
            full[retry] = pair[choice, np.arange(retry.size)]
    roots, shading, remaining, residual, fitted, damping = out

    moving = np.flatnonzero(remaining > step_tol)
    for _ in range(max_rounds):  # gathered, so that converged pixels cost nothing more
        if not moving.size:
            break
        more = map_batches(spline(straggler_steps), (target[moving], roots[moving], damping[moving]), _SUBSET_CHUNK)
        for full, part in zip(out, more):
            full[moving] = part
        moving = moving[remaining[moving] > step_tol]
    if moving.size and lm_max_steps:
        lm = lambda t, r: _levenberg_marquardt(coefficients, r, t, lm_max_steps, 1e-10, 1e-12)  # noqa: E731
        lm_roots, lm_ok = map_batches(lm, (target[moving], roots[moving]), pad_size(moving.size, 256))
        final = map_batches(spline(0), (target[moving], lm_roots, damping[moving]), pad_size(moving.size, 256))
        for full, part in zip(out, final):
            full[moving] = part
        remaining[moving] = np.where(lm_ok, 0.0, np.inf)
    return out[:5]


#: Chunk size for the subsets that go round again (second branch, stragglers): one size, so one
#: compilation whatever the subset's size; small enough that padding wastes little, large enough
#: to keep dispatch overhead negligible.
_SUBSET_CHUNK = 2048


def _choose_branch(shading, residual, reference: float) -> np.ndarray:
    """Per pixel, the branch (0 or 1) that fits and whose shading is nearest the reference.

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
    ``white_balance`` are the camera gains (r, g, b) the fit divided out (1 unless fitted):
    ``fitted_linear_rgb`` includes them.
    """

    melanin: np.ndarray
    melanin_blend: np.ndarray
    haemoglobin: np.ndarray
    shading: np.ndarray
    residual_dE2000: np.ndarray
    status: np.ndarray
    fitted_linear_rgb: np.ndarray  # (h, w, 3)
    seconds: float
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    model: SkinModel | None = None

    @property
    def model_name(self) -> str:
        return resolve_model(self.model).name

    MAP_NAMES = ("melanin", "melanin_blend", "haemoglobin", "shading", "residual_dE2000", "status")

    def maps(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in self.MAP_NAMES}

    def render(self, scale_melanin: float = 1.0, scale_haemoglobin: float = 1.0, illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
        """Linear sRGB (h, w, 3) of the maps with scaled melanin and haemoglobin (an edit), through
        the exact model and the fitted white balance. Pixels with maps (status up to
        ``OUT_OF_MODEL``) are rendered; the others keep their fitted colour (0)."""
        edited = render_maps(
            scale_melanin * self.melanin, scale_haemoglobin * self.haemoglobin, self.shading,
            melanin_blend=self.melanin_blend, illuminant=illuminant, model=self.model,
        ) * np.asarray(self.white_balance)
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
            "model": self.model_name,
            "seconds": self.seconds,
        }


def fit_image(
    image,
    *,
    melanin_blend: float = 0.7,
    fit_blend: bool = False,
    white_balance: bool | tuple[float, float, float] = False,
    input_space: str | None = None,
    mask=None,
    use_alpha: bool = True,
    illuminant: str = DEFAULT_ILLUMINANT,
    method: str | None = None,
    model: SkinModel | None = None,
    progress: bool | None = None,
    **options,
) -> ImageFit:
    """Fit melanin, haemoglobin and shading maps to a photo or albedo image.

    Args:
        image: a path (read through OpenImageIO, see ``skinfit.images``) or a linear sRGB array
            (h, w, 3).
        melanin_blend: beta_m for the whole image (three channels cannot carry it per pixel).
        fit_blend: fit beta_m once for the whole image instead (``skinfit.calibration``).
        white_balance: ``True`` fits per-channel camera gains once for the image (for photos
            under unknown light); a tuple (r, g, b) gives them; ``False``: none (albedo maps).
        input_space: encoding of a file (``None``: from its type and metadata).
        mask: (h, w) array or image path; pixels where it is 0 are not fitted (status MASKED).
        use_alpha: treat the file's alpha channel as a mask.
        illuminant: the illuminant of the camera model (colour-science name; D65 default).
        model: the ``SkinModel`` (default: the package default); ``method`` overrides its forward
            method as in ``fit_pixels``.
        **options: passed to ``fit_pixels`` (steps, max_delta_e, chunk_size, ...).
    """
    import time

    from .images import read_linear_rgb, read_mask

    start = time.perf_counter()
    model = model_with_options(model, method=method)
    alpha = None
    if _is_path(image):
        rgb, alpha = read_linear_rgb(image, input_space)
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
    gains = np.ones(3)
    if fit_blend or white_balance is True:
        from .calibration import calibrate

        pixels = rgb.reshape(-1, 3)
        screened, _ = _screen(pixels, mask, options.get("black_level", 1e-4), options.get("saturation_level", 0.999))
        fittable = screened == PixelStatus.SUCCESS
        if not fittable.any():
            raise SkinfitInputError("no pixel of the image can be fitted (all black, saturated, masked or invalid)")
        calibration = calibrate(
            pixels[fittable], melanin_blend=None if fit_blend else melanin_blend, white_balance=white_balance is True, illuminant=illuminant,
            model=model,
        )
        melanin_blend, gains = calibration.melanin_blend, np.asarray(calibration.white_balance)
    elif white_balance is not False:
        gains = np.asarray(white_balance, dtype=float)
        if gains.shape != (3,) or not np.all(gains > 0):
            raise SkinfitInputError(f"white_balance must be True, False or three positive gains, got {white_balance}")
    maps = _fit_in_bands(rgb, gains, mask, dict(melanin_blend=melanin_blend, illuminant=illuminant, model=model, **options), progress)
    fitted = maps.pop("fitted_rgb")
    return ImageFit(**maps, fitted_linear_rgb=fitted, seconds=time.perf_counter() - start, white_balance=tuple(float(g) for g in gains),
                    model=model)


def _fit_in_bands(rgb, gains, mask, options, progress, band_pixels: int = 1 << 20):
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

