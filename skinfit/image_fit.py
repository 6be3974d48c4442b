"""Per-pixel inversion of linear RGB images to melanin, haemoglobin and shading maps.

Camera model: a pixel's linear sRGB (D65 white = 1) is

    rgb = shading * M W R(lambda; C_m, beta_m, C_h)

with R the DJ2006 diffuse reflectance, W the CIE 1931 2-degree colour matching functions weighted by
the illuminant (D65 by default, Bradford-adapted to D65 otherwise) and M the XYZ -> linear sRGB
matrix (``skinfit.colorimetry``). Three channels carry three unknowns per pixel: C_m, C_h and the
shading; the melanin blend is fixed for the whole image.

Fast path. With the blend fixed, the model colour is a smooth function of two variables, tabulated
once on a fine grid in (sqrt C_m, sqrt C_h) in [0, 1]^2 (square roots spread the grid where the
colour changes fastest, near zero) and interpolated bilinearly. Per pixel:

1. warm start: the coarse-grid entry whose chromaticity is closest (largest cosine);
2. polish: Gauss-Newton on the interpolated table in lock-step over a chunk, with the shading
   eliminated in closed form (variable projection: for a colour m the best shading is
   t.m / m.m), the residual relative to the pixel's brightness so that dark and bright pixels
   weigh alike, and the unknowns projected onto the box after each step.

Pixels that cannot be fitted get a status code and zeros, never NaN.
"""

from __future__ import annotations

import dataclasses
import enum
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ._batching import map_batches, pad_size
from ._linalg import solve_normal
from ._validate import SkinfitInputError
from .colorimetry import DEFAULT_ILLUMINANT, linear_srgb_weights
from .params import SkinParams
from .reflectance import diffuse_reflectance

#: The box of the image fit. Three channels cannot tell heavy melanin with much blood from heavy
#: melanin with little (the colour map folds over: at C_m 0.37 the colours of C_h 0.075 and 0.36
#: agree to CIEDE2000 0.02), so the haemoglobin range stops at physiological blood fractions.
MELANIN_MAX = 0.5
HAEMOGLOBIN_MAX = 0.15

#: Wavelengths of the colour integral (nm).
COLOUR_WAVELENGTHS_NM = np.arange(400.0, 701.0, 10.0)


class PixelStatus(enum.IntEnum):
    """Per-pixel outcome of ``fit_pixels``."""

    SUCCESS = 0  #: converged; maps hold the fit
    MAX_STEPS = 1  #: stopped at the step limit; maps hold the best iterate
    OUT_OF_MODEL = 2  #: converged, but CIEDE2000 to the pixel exceeds ``max_delta_e`` (not skin?)
    BAD_INPUT = 3  #: NaN, Inf or negative values
    MASKED = 4  #: outside the mask
    BLACK = 5  #: too dark to carry colour
    SATURATED = 6  #: a channel at the clipping level


@dataclasses.dataclass(frozen=True)
class ColourTable:
    """The skin model's linear sRGB (shading 1) over the parameter box, and its inverse.

    ``rgb[i, j]`` is the colour at C_m = melanin_max (i / (size - 1))^2 and
    C_h = haemoglobin_max (j / (size - 1))^2; the fit works on these normalised roots.
    ``inverse_roots[a, b, k]`` are two roots whose chromaticity is near the centre of cell (a, b) of
    a grid over chromaticity (r / (r + g + b), g / (r + g + b)) spanning ``chromaticity_box`` =
    (r_low, r_high, g_low, g_high): the nearest, and the nearest on another branch of the fold
    (the same root if there is none). Warm starts, one lookup per pixel.
    """

    melanin_blend: float
    illuminant: str
    melanin_max: float
    haemoglobin_max: float
    rgb: np.ndarray  # (size, size, 3)
    inverse_roots: np.ndarray  # (cells, cells, 2 branches, 2)
    chromaticity_box: tuple[float, float, float, float]


@functools.lru_cache(maxsize=8)
def colour_table(
    melanin_blend: float = 0.7,
    illuminant: str = DEFAULT_ILLUMINANT,
    melanin_max: float = MELANIN_MAX,
    haemoglobin_max: float = HAEMOGLOBIN_MAX,
    size: int = 257,
    cells: int = 256,
) -> ColourTable:
    """The model's colours over the parameter box (cached per blend, illuminant and box)."""
    from scipy.spatial import cKDTree

    if not 0.0 <= melanin_blend <= 1.0:
        raise SkinfitInputError(f"melanin_blend must be within [0, 1], got {melanin_blend}")
    root = np.linspace(0.0, 1.0, size)
    sm, sh = np.meshgrid(root, root, indexing="ij")
    all_roots = np.stack([sm.ravel(), sh.ravel()], axis=-1)
    weights = jnp.asarray(linear_srgb_weights(COLOUR_WAVELENGTHS_NM, illuminant))
    exact = jax.jit(_exact_rgb)(jnp.asarray(all_roots), melanin_blend, melanin_max, haemoglobin_max, weights)
    rgb = np.asarray(exact).reshape(size, size, 3)
    chroma = _chromaticity(rgb.reshape(-1, 3))
    low, high = chroma.min(axis=0), chroma.max(axis=0)
    pad = 0.05 * (high - low)
    low, high = low - pad, high + pad
    centres = [low[k] + (np.arange(cells) + 0.5) * (high[k] - low[k]) / cells for k in range(2)]
    grid = np.stack(np.meshgrid(*centres, indexing="ij"), axis=-1).reshape(-1, 2)
    # The colour map folds: one chromaticity can come from two parameter sets of different
    # brightness. Keep the nearest entry and the nearest one far from it in parameters (or the
    # nearest again): the fit tries both and lets the shading decide.
    _, near = cKDTree(chroma).query(grid, k=64)
    first = all_roots[near[:, 0]]
    far = np.linalg.norm(all_roots[near] - first[:, None], axis=-1) > 0.1
    second = np.where(far.any(axis=1)[:, None], all_roots[near[np.arange(len(near)), np.argmax(far, axis=1)]], first)
    roots = np.stack([first, second], axis=1).reshape(cells, cells, 2, 2)
    box = (low[0], high[0], low[1], high[1])
    return ColourTable(float(melanin_blend), illuminant, float(melanin_max), float(haemoglobin_max), rgb, roots, box)


def _chromaticity(rgb):
    total = rgb.sum(axis=-1, keepdims=True)
    return rgb[..., :2] / np.where(total > 0, total, 1.0)


def _bilinear(table_rgb, roots):
    """Bilinear interpolation of the table at roots (..., 2) in [0, 1]: the colour (..., 3) and its
    derivatives with respect to both roots, each (..., 3)."""
    size = table_rgb.shape[0]
    x = jnp.clip(roots, 0.0, 1.0) * (size - 1)
    cell = jnp.clip(jnp.floor(x), 0, size - 2)
    frac = x - cell
    i, j = cell[..., 0].astype(jnp.int32), cell[..., 1].astype(jnp.int32)
    a, b = frac[..., 0:1], frac[..., 1:2]
    c00, c10, c01, c11 = table_rgb[i, j], table_rgb[i + 1, j], table_rgb[i, j + 1], table_rgb[i + 1, j + 1]
    twist = c11 - c10 - c01 + c00
    colour = c00 + a * (c10 - c00) + b * (c01 - c00) + a * b * twist
    return colour, (size - 1) * (c10 - c00 + b * twist), (size - 1) * (c01 - c00 + a * twist)


@functools.partial(jax.jit, static_argnames=("steps",))
def _fit_chunk(table_rgb, inverse_roots, box, target, steps):
    """Warm start from the inverse table, then lock-step Gauss-Newton, for pixels (n, 3).

    Returns the roots (n, 2), the shading (n,), the size of the last step (n,), the relative
    residual (n,) and the fitted colour (n, 3).
    """
    total = jnp.sum(target, axis=-1, keepdims=True)
    chroma = target[:, :2] / total
    cells = inverse_roots.shape[0]
    low, high = jnp.stack([box[0], box[2]]), jnp.stack([box[1], box[3]])
    index = jnp.clip(jnp.floor((chroma - low) / (high - low) * cells), 0, cells - 1).astype(jnp.int32)
    roots = inverse_roots[index[:, 0], index[:, 1]]
    scale = 1.0 / jnp.linalg.norm(target, axis=-1)

    def residual_and_jacobian(roots):
        # Variable projection: the best shading k = t.m / m.m for each colour m; residual relative
        # to the pixel's brightness, r = (t - k m) / |t|.
        m, dm_a, dm_b = _bilinear(table_rgb, roots)
        mm = jnp.sum(m * m, -1)
        tm = jnp.sum(target * m, -1)
        k = tm / mm
        r = (target - k[:, None] * m) * scale[:, None]

        def d_residual(dm):
            dk = jnp.sum(target * dm, -1) / mm - tm * 2.0 * jnp.sum(m * dm, -1) / mm**2
            return -(dk[:, None] * m + k[:, None] * dm) * scale[:, None]

        return r, d_residual(dm_a), d_residual(dm_b), k, m

    last = jnp.zeros(target.shape[0], target.dtype)
    for _ in range(steps):
        r, ja, jb, _, _ = residual_and_jacobian(roots)
        # 2x2 normal equations in closed form
        aa, ab, bb = jnp.sum(ja * ja, -1), jnp.sum(ja * jb, -1), jnp.sum(jb * jb, -1)
        ga, gb = jnp.sum(ja * r, -1), jnp.sum(jb * r, -1)
        floor = 1e-12 * jnp.maximum(aa, bb) + 1e-300
        aa, bb = aa + floor, bb + floor
        det = aa * bb - ab * ab
        step = jnp.stack([-(bb * ga - ab * gb) / det, -(aa * gb - ab * ga) / det], axis=-1)
        step = jnp.where(jnp.isfinite(step), step, 0.0)
        new = jnp.clip(roots + jnp.clip(step, -0.05, 0.05), 0.0, 1.0)  # a few table cells at most
        last = jnp.max(jnp.abs(new - roots), axis=-1)
        roots = new
    r, _, _, shading, m = residual_and_jacobian(roots)
    return roots, shading, last, jnp.linalg.norm(r, axis=-1), shading[:, None] * m


@jax.jit
def _rgb_of_params(columns, weights):
    """Linear sRGB (shading 1) of (C_m, beta_m, C_h) rows."""
    reflectance = diffuse_reflectance(SkinParams(columns[:, 0], columns[:, 1], columns[:, 2]), COLOUR_WAVELENGTHS_NM)
    return reflectance @ weights.T


def _exact_rgb(roots, melanin_blend, melanin_max, haemoglobin_max, weights):
    """Linear sRGB (shading 1) of the exact forward model at normalised roots (n, 2)."""
    c_m = melanin_max * jnp.clip(roots[:, 0], 0.0, 1.0) ** 2
    c_h = haemoglobin_max * jnp.clip(roots[:, 1], 0.0, 1.0) ** 2
    return _rgb_of_params(jnp.stack([c_m, jnp.full_like(c_m, melanin_blend), c_h], axis=-1), weights)


@functools.partial(jax.jit, static_argnames=("steps",))
def _polish_chunk(roots, target, melanin_blend, melanin_max, haemoglobin_max, weights, steps):
    """Gauss-Newton steps on the exact model (the table's interpolation error is ~1e-6, more than
    haemoglobin changes the colour under heavy melanin). Returns roots, shading, last step size and
    the fitted colour (n, 3)."""
    scale = 1.0 / jnp.linalg.norm(target, axis=-1)

    def projected(r, t, s):
        """(relative residual, its copy as aux) and the shading k and colour k m."""
        m = _exact_rgb(r[None], melanin_blend, melanin_max, haemoglobin_max, weights)[0]
        k = jnp.dot(t, m) / jnp.dot(m, m)
        residual = (t - k * m) * s
        return residual, (residual, k, k * m)

    def step(r, t, s):
        jac, (res, _, _) = jax.jacfwd(lambda x: projected(x, t, s), has_aux=True)(r)
        delta = solve_normal(jac.T @ jac, -(jac.T @ res))
        delta = jnp.where(jnp.all(jnp.isfinite(delta)), jnp.clip(delta, -0.05, 0.05), 0.0)
        new = jnp.clip(r + delta, 0.0, 1.0)
        return new, jnp.max(jnp.abs(new - r))

    last = jnp.zeros(target.shape[0], target.dtype)
    for _ in range(steps):
        roots, last = jax.vmap(step)(roots, target, scale)
    _, (_, shading, fitted) = jax.vmap(lambda r, t, s: projected(r, t, s))(roots, target, scale)
    return roots, shading, last, fitted


def fit_pixels(
    linear_rgb: np.ndarray,
    *,
    melanin_blend: float = 0.7,
    illuminant: str = DEFAULT_ILLUMINANT,
    mask: np.ndarray | None = None,
    steps: int = 8,
    polish_steps: int = 2,
    max_polish_rounds: int = 8,
    step_tol: float = 1e-7,
    shading_reference: float | None = None,
    max_delta_e: float = 5.0,
    black_level: float = 1e-4,
    saturation_level: float = 0.999,
    chunk_size: int = 16384,
    progress: bool | None = None,
) -> dict[str, np.ndarray]:
    """Fit every pixel of a linear sRGB image (h, w, 3) (or pixels (n, 3)).

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
    status = np.full(len(pixels), PixelStatus.SUCCESS, dtype=np.uint8)
    finite = np.all(np.isfinite(pixels), axis=1)
    status[~finite | np.any(pixels < 0, axis=1) & finite] = PixelStatus.BAD_INPUT
    clean = np.where(finite[:, None], pixels, 0.0)
    status[(status == 0) & (clean.max(axis=1) < black_level)] = PixelStatus.BLACK
    status[(status == 0) & (clean.max(axis=1) >= saturation_level)] = PixelStatus.SATURATED
    if mask is not None:
        mask = np.asarray(mask).reshape(-1)
        if mask.shape[0] != len(pixels):
            raise SkinfitInputError(f"mask has {mask.shape[0]} pixels, the image {len(pixels)}")
        status[(status == 0) & ~(mask > 0)] = PixelStatus.MASKED

    table = colour_table(float(melanin_blend), illuminant)
    table_rgb, inverse_roots = jnp.asarray(table.rgb), jnp.asarray(table.inverse_roots)
    box = jnp.asarray(table.chromaticity_box)
    exact = (float(melanin_blend), table.melanin_max, table.haemoglobin_max, jnp.asarray(linear_srgb_weights(COLOUR_WAVELENGTHS_NM, illuminant)))

    todo = np.flatnonzero(status == 0)
    roots = np.zeros((len(pixels), 2))
    shading = np.zeros(len(pixels))
    last_step = np.zeros(len(pixels))
    fitted = np.zeros((len(pixels), 3))
    if todo.size:
        size = pad_size(todo.size, chunk_size)
        # table pass: each branch of the fold from its own warm start; per branch the outputs of
        # _fit_chunk for every pixel to fit (roots, shading, last step, residual, colour)
        branches = [
            map_batches(lambda t: _fit_chunk(table_rgb, starts, box, t, steps), (clean[todo],), size, progress, "fitting pixels")
            for starts in jnp.moveaxis(inverse_roots, 2, 0)
        ]
        stacked = [np.stack(quantity) for quantity in zip(*branches)]  # each (branches, n, ...)
        choice = _choose_branch(stacked[0], stacked[1], stacked[3], shading_reference)
        chosen = [q[choice, np.arange(todo.size)] for q in stacked]
        roots[todo], shading[todo], last_step[todo], fitted[todo] = chosen[0], chosen[1], chosen[2], chosen[4]
        if polish_steps:  # exact-model polish of the chosen branch; stragglers gathered for more
            active, rounds = todo, 0
            while active.size and rounds <= max_polish_rounds:
                count = polish_steps if rounds == 0 else 4
                batch = size if rounds == 0 else min(size, 1024)
                polish = lambda t, r: _polish_chunk(r, t, *exact, count)  # noqa: E731
                out = map_batches(polish, (clean[active], roots[active]), batch)
                roots[active], shading[active], last_step[active], fitted[active] = out
                active = active[last_step[active] > step_tol]
                rounds += 1
    delta_e = np.zeros(len(pixels))
    if todo.size:
        delta_e[todo] = _delta_e2000_rgb(clean[todo], fitted[todo], illuminant)
        converged = last_step[todo] <= step_tol
        status[todo[~converged]] = PixelStatus.MAX_STEPS
        status[todo[converged & (delta_e[todo] > max_delta_e)]] = PixelStatus.OUT_OF_MODEL
    fitted_any = np.isin(status, (PixelStatus.SUCCESS, PixelStatus.MAX_STEPS, PixelStatus.OUT_OF_MODEL))
    maps = {
        "melanin": table.melanin_max * roots[:, 0] ** 2,
        "melanin_blend": np.full(len(pixels), float(melanin_blend)),
        "haemoglobin": table.haemoglobin_max * roots[:, 1] ** 2,
        "shading": shading,
        "residual_dE2000": delta_e,
    }
    for values in maps.values():
        values[~fitted_any] = 0.0
    fitted[~fitted_any] = 0.0
    maps["status"] = status
    maps["fitted_rgb"] = fitted
    return {k: v.reshape(*shape, *v.shape[1:]) for k, v in maps.items()}


def _choose_branch(roots, shading, residual, reference) -> np.ndarray:
    """Per pixel, the branch (0 or 1) that fits and whose shading is nearest the reference.

    Branches whose relative residual is within 1 % of the best fit equally well (8-bit
    quantisation alone leaves residuals of 1e-3); among them the shading decides. The reference defaults to the median shading of the pixels whose branches
    agree (one exposure for the image), else 1.
    """
    fits = residual <= residual.min(axis=0) + 1e-2
    if reference is None:
        agree = np.linalg.norm(roots[0] - roots[-1], axis=-1) < 0.02
        good = shading[0][agree & fits[0] & (shading[0] > 0)]
        reference = float(np.median(good)) if good.size else 1.0
    distance = np.abs(np.log(np.maximum(shading, 1e-12) / reference))
    return np.argmin(np.where(fits, distance, np.inf), axis=0)


def _delta_e2000_rgb(measured, fitted, illuminant) -> np.ndarray:
    """CIEDE2000 between linear sRGB colours (white = 1), via colour-science."""
    import colour

    space = colour.RGB_COLOURSPACES["sRGB"]
    white = space.whitepoint
    lab = [colour.XYZ_to_Lab(colour.RGB_to_XYZ(c, space, apply_cctf_decoding=False), white) for c in (measured, fitted)]
    return np.asarray(colour.delta_E(lab[0], lab[1], method="CIE 2000"), dtype=float)


@dataclasses.dataclass(frozen=True)
class ImageFit:
    """Parameter maps of one image (each (h, w)), its reconstruction and a summary.

    ``status`` holds ``PixelStatus`` codes; pixels that were not fitted hold 0 in every map.
    """

    melanin: np.ndarray
    melanin_blend: np.ndarray
    haemoglobin: np.ndarray
    shading: np.ndarray
    residual_dE2000: np.ndarray
    status: np.ndarray
    fitted_linear_rgb: np.ndarray  # (h, w, 3)
    seconds: float

    MAP_NAMES = ("melanin", "melanin_blend", "haemoglobin", "shading", "residual_dE2000", "status")

    def maps(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in self.MAP_NAMES}

    def summary(self) -> dict[str, float]:
        """Pixels, fitted fraction, median and 95th-percentile CIEDE2000 of the fitted pixels, time."""
        fitted = self.status == PixelStatus.SUCCESS
        delta_e = self.residual_dE2000[fitted]
        return {
            "pixels": int(self.status.size),
            "fitted": int(fitted.sum()),
            "fitted_fraction": float(fitted.mean()),
            "median_dE2000": float(np.median(delta_e)) if delta_e.size else float("nan"),
            "p95_dE2000": float(np.percentile(delta_e, 95)) if delta_e.size else float("nan"),
            "seconds": self.seconds,
        }


def fit_image(
    image,
    *,
    melanin_blend: float = 0.7,
    input_space: str | None = None,
    mask=None,
    use_alpha: bool = True,
    illuminant: str = DEFAULT_ILLUMINANT,
    progress: bool | None = None,
    **options,
) -> ImageFit:
    """Fit melanin, haemoglobin and shading maps to a photo or albedo image.

    Args:
        image: a path (read through OpenImageIO, see ``skinfit.images``) or a linear sRGB array
            (h, w, 3).
        melanin_blend: beta_m for the whole image (three channels cannot carry it per pixel).
        input_space: encoding of a file (``None``: from its type and metadata).
        mask: (h, w) array or image path; pixels where it is 0 are not fitted (status MASKED).
        use_alpha: treat the file's alpha channel as a mask.
        illuminant: the illuminant of the camera model (colour-science name; D65 default).
        **options: passed to ``fit_pixels`` (steps, max_delta_e, chunk_size, ...).
    """
    import time

    from .images import read_linear_rgb

    start = time.perf_counter()
    alpha = None
    if _is_path(image):
        rgb, alpha = read_linear_rgb(image, input_space)
    else:
        rgb = np.asarray(image, dtype=float)
        if rgb.ndim != 3 or rgb.shape[-1] != 3:
            raise SkinfitInputError(f"expected an image of shape (h, w, 3), got {rgb.shape}")
    if _is_path(mask):
        mask_rgb, mask_alpha = read_linear_rgb(mask, "linear")
        mask = mask_rgb.max(axis=-1) if mask_alpha is None else mask_alpha
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != rgb.shape[:2]:
            raise SkinfitInputError(f"mask has shape {mask.shape}, the image {rgb.shape[:2]}")
    if use_alpha and alpha is not None:
        mask = alpha if mask is None else np.minimum(mask, alpha)
    maps = fit_pixels(rgb, melanin_blend=melanin_blend, illuminant=illuminant, mask=mask, progress=progress, **options)
    fitted = maps.pop("fitted_rgb")
    return ImageFit(**maps, fitted_linear_rgb=fitted, seconds=time.perf_counter() - start)


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
) -> np.ndarray:
    """Linear sRGB (h, w, 3) of parameter maps through the exact forward model and camera model.

    Maps (h, w) in physical units (volume fractions; the blend may be a map or one value) are
    clipped to [0, 1]; pixels go through in fixed-size chunks, so memory stays bounded.
    """
    melanin, haemoglobin, shading = (np.asarray(a, dtype=float) for a in (melanin, haemoglobin, shading))
    blend = np.broadcast_to(np.asarray(melanin_blend, dtype=float), melanin.shape)
    columns = np.stack([np.clip(a, 0.0, 1.0).ravel() for a in (melanin, blend, haemoglobin)], axis=-1)
    weights = jnp.asarray(linear_srgb_weights(COLOUR_WAVELENGTHS_NM, illuminant))
    (rgb,) = map_batches(
        lambda c: (_rgb_of_params(c, weights),), (columns,), pad_size(len(columns), chunk_size)
    )
    return shading[..., None] * rgb.reshape(*melanin.shape, 3)

