"""The skin model's colour over (melanin, haemoglobin) as a bicubic spline, and its inverse.

With the melanin blend fixed for an image, the model's linear sRGB (shading 1) is a smooth function
of two variables. It is tabulated on a grid in the normalised roots

    u = sqrt(C_m / melanin_max),  v = sqrt(C_h / haemoglobin_max),  (u, v) in [0, 1]^2

(square roots spread the nodes where the colour changes fastest, near zero; the colour is smooth
in them since it is smooth in C_m and C_h). Each node stores the exact colour and its exact first
and mixed derivatives (forward-mode autodiff of the model), and each cell holds the bicubic
Hermite patch through its four corners: C^1 across cells, interpolation error O(h^4). On the
default 129 x 129 grid the spline matches the model to ~1e-9 in linear sRGB (measured in
``tests/colorimetry/test_colour_table.py``), far below 16-bit quantisation, at the cost of a few hundred flops
per evaluation instead of the ~31-wavelength model.

The inverse: a grid over chromaticity (r, g) / (r + g + b) stores, per cell, two warm starts (u, v):
the sample of nearest chromaticity and the nearest one on another branch of the fold (the colour
map folds over: with the shading free, (C_m 0.057, C_h 0.074, shading 0.75) and
(0.0175, 0.0067, 0.374) look the same), each with its chromaticity and the inverse of its
chromaticity Jacobian, so that a pixel's start is a Newton step in chromaticity (which the shading
does not move) from its cell's: on the round-trip image 81 % of the pixels then converge in one
Levenberg-Marquardt step (53 % with the Newton step limited to 0.01 in the roots, under 1 % from the cell's start alone).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._batching import map_batches
from .._caching import BoundedCache, eager_cached_property
from .._disk_cache import load_arrays, save_arrays
from .._validate import SkinfitInputError
from ..model import (
    SkinModel,
    SkinParams,
    cache_key,
    model_with_options,
    skin_reflectance,
)
from ._cie import DEFAULT_ILLUMINANT, linear_srgb_weights

#: The box of the image fit. Three channels cannot tell heavy melanin with much blood from heavy
#: melanin with little (the colour map folds over: at C_m 0.37 the colours of C_h 0.075 and 0.36
#: agree to CIEDE2000 0.02), so the haemoglobin range stops at physiological blood fractions.
MELANIN_MAX = 0.5
HAEMOGLOBIN_MAX = 0.15

#: The box of dark skin's faces (``skinfit.fit`` takes it for a face whose own fits reach the edge of
#: the box above): the calibrated model's spectral fits of ISSA's African cheeks reach melanin 0.84 and
#: haemoglobin 0.44 (``benchmarks/fit_image_tones.py``), and the box above left two thirds of those
#: faces' pixels pinned at its top. Not the default: a wider box lets more colours of light skin reach
#: a second exact solution of the fold (a quarter of noisy copies of DJ2006's (0.05, 0.02) at 0.2 %).
DARK_MELANIN_MAX = 1.0
DARK_HAEMOGLOBIN_MAX = 0.5

#: Largest move of a warm start along its chromaticity Jacobian (normalised roots): the linear
#: model is poor near the fold, where the Jacobian is near singular.
_AFFINE_REACH = 0.3

#: Spline nodes per axis of a transport table, whose node derivatives come from an interpolating
#: spline (error against exact transport measured in tests/colorimetry/test_colour_table.py).
TRANSPORT_NODES = 33

#: Roots per axis of the spline sampling that ``ColourTable.starts_for_colours`` searches, and the
#: floor of the colours' logarithms there.
_SEARCH_NODES = 97
_LOG_FLOOR = 1e-6

#: Wavelengths of the colour integral (nm).
COLOUR_WAVELENGTHS_NM = np.arange(400.0, 701.0, 10.0)

# Bicubic Hermite basis: for values and slopes (p0, p1, d0, d1) on [0, 1] the cubic's monomial
# coefficients are _HERMITE @ (p0, p1, d0, d1).
_HERMITE = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [-3.0, 3.0, -2.0, -1.0], [2.0, -2.0, 1.0, 1.0]])


@dataclasses.dataclass(frozen=True)
class ColourTable:
    """The model's colour spline over the normalised roots and the inverse warm-start table.

    ``coefficients[i * cells + j, 3 * (4 p + q) + c]`` is the coefficient of a^p b^q for channel c
    in cell (i, j), with (a, b) the position within the cell in [0, 1]^2.
    ``inverse_roots[a, b, k]`` are the two warm starts (u, v) for chromaticity cell (a, b) of the
    grid whose interior cell edges along r and g are ``inverse_edges`` (the outer cells extend to
    infinity), ``inverse_chroma`` their chromaticities and ``inverse_jacobian`` the derivatives of
    the roots along the chromaticity there (float32: they only start the solver).
    """

    melanin_blend: float
    illuminant: str
    melanin_max: float
    haemoglobin_max: float
    nodes: int
    coefficients: np.ndarray  # (cells^2, 48)
    inverse_roots: np.ndarray  # (inverse_cells, inverse_cells, 2 branches, 2)
    inverse_chroma: np.ndarray  # (inverse_cells, inverse_cells, 2 branches, 2)
    inverse_jacobian: np.ndarray  # (inverse_cells, inverse_cells, 2 branches, 2 roots, 2 chroma)
    inverse_edges: tuple[np.ndarray, np.ndarray]
    model: SkinModel

    def warm_starts(self, pixels: np.ndarray) -> np.ndarray:
        """Both warm starts (n, 2 branches, 2) for linear sRGB pixels (n, 3) (see ``warm_starts``)."""
        return np.asarray(warm_starts(self.device_inverse, jnp.asarray(pixels)))

    @eager_cached_property
    def device_inverse(self) -> tuple:
        """The inverse table as JAX arrays, for ``warm_starts`` inside compiled code."""
        arrays = (*self.inverse_edges, self.inverse_roots, self.inverse_chroma, self.inverse_jacobian)
        return tuple(jnp.asarray(a) for a in arrays)

    def starts_for_colours(self, colours: np.ndarray) -> np.ndarray:
        """Roots (n, 2) whose spline colour (shading 1) is nearest each of ``colours`` (n, 3), linear
        sRGB, in log colour: a start for a pixel whose shading is known (``colours`` = the pixel
        over it), on whichever branch of the fold that shading selects."""
        return self._colour_search[0][self._nearest(colours)[1]]

    def colour_distance(self, colours: np.ndarray, upper_bound: float = np.inf) -> np.ndarray:
        """Distance (n,) in log colour (about the relative colour error) from each of ``colours``
        (n, 3) to the nearest colour of the spline's sampling (``_SEARCH_NODES`` per axis); inf
        beyond ``upper_bound``, which prunes the search (150,000 colours: 1.27 s without, 0.017 s at 0.03)."""
        return self._nearest(colours, upper_bound)[0]

    def _nearest(self, colours, upper_bound: float = np.inf):
        _, tree = self._colour_search
        return tree.query(np.log(np.maximum(np.asarray(colours, dtype=float), _LOG_FLOOR)), distance_upper_bound=upper_bound, workers=-1)

    @eager_cached_property
    def _colour_search(self):
        from scipy.spatial import cKDTree

        grid = np.linspace(0.0, 1.0, _SEARCH_NODES)
        roots = np.stack([a.ravel() for a in np.meshgrid(grid, grid, indexing="ij")], axis=-1)
        colours = np.asarray(spline_rgb(jnp.asarray(self.coefficients), jnp.asarray(roots))[0])
        return roots, cKDTree(np.log(np.maximum(colours, _LOG_FLOOR)))

    def model_arguments(self):
        """(melanin_blend, melanin_max, haemoglobin_max, weights, model): what ``model_rgb``
        needs after the roots to evaluate the exact model this table interpolates."""
        weights = jnp.asarray(linear_srgb_weights(COLOUR_WAVELENGTHS_NM, self.illuminant))
        return self.melanin_blend, self.melanin_max, self.haemoglobin_max, weights, self.model

    def parameters(self, roots):
        """(C_m, C_h) of normalised roots (..., 2)."""
        roots = np.clip(np.asarray(roots, dtype=float), 0.0, 1.0)
        return self.melanin_max * roots[..., 0] ** 2, self.haemoglobin_max * roots[..., 1] ** 2


def colour_table(
    melanin_blend: float = 0.7,
    illuminant: str = DEFAULT_ILLUMINANT,
    melanin_max: float = MELANIN_MAX,
    haemoglobin_max: float = HAEMOGLOBIN_MAX,
    nodes: int | None = None,
    inverse_cells: int = 512,
    method: str | None = None,
    *,
    model: SkinModel | None = None,
) -> ColourTable:
    """Build (and cache per blend, illuminant, box, size and model) the colour spline and its inverse.

    ``model``: the ``SkinModel`` (default: the package default); ``method`` overrides its forward
    method as in ``diffuse_reflectance``. ``nodes`` per axis default to 129 (node derivatives by
    forward-mode autodiff), and to ``TRANSPORT_NODES`` for direct adding-doubling (``method="transport-direct"``:
    thousands of times the cost per spectrum on a CPU; measured 4 s on an H100, 1-2 min on a 2-core
    CPU; once per process), whose node derivatives come from an interpolating spline."""
    if not 0.0 <= melanin_blend <= 1.0:
        raise SkinfitInputError(f"melanin_blend must be within [0, 1], got {melanin_blend}")
    model = model_with_options(model, method=method)
    direct = model.method.solves_directly
    if nodes is None:
        nodes = TRANSPORT_NODES if direct else 129
    key = (float(melanin_blend), str(illuminant), float(melanin_max), float(haemoglobin_max), int(nodes), int(inverse_cells),
           cache_key(model))
    # coarse tables (the blend search's, skinfit.fit) are kept apart: a search over 20 blends must
    # not push the full-size tables a fit is using out of their cache
    cache = _TABLES if inverse_cells >= 512 else _COARSE_TABLES
    build = lambda: _colour_table(float(melanin_blend), str(illuminant), float(melanin_max), float(haemoglobin_max),  # noqa: E731
                                  int(nodes), int(inverse_cells), model, direct)
    return cache.get(key, lambda: _stored_or_built(key, model, build))


_TABLES = BoundedCache(8)
_COARSE_TABLES = BoundedCache(48)

#: The arrays of a ``ColourTable`` that ``skinfit._disk_cache`` keeps between processes.
_STORED = ("coefficients", "inverse_roots", "inverse_chroma", "inverse_jacobian")


def _stored_or_built(key, model, build) -> ColourTable:
    """The table of ``key`` from the disk cache (a second process, the same code and model), else
    ``build()`` and saved there."""
    melanin_blend, illuminant, melanin_max, haemoglobin_max, nodes = key[:5]
    stored = load_arrays("colour-tables", key)
    if stored is not None and set(stored) == {*_STORED, "edges_r", "edges_g"}:
        arrays = [stored[name] for name in _STORED]
        return ColourTable(melanin_blend, illuminant, melanin_max, haemoglobin_max, nodes, *arrays,
                           (stored["edges_r"], stored["edges_g"]), model)
    table = build()
    save_arrays("colour-tables", key, {**{name: getattr(table, name) for name in _STORED},
                                       "edges_r": table.inverse_edges[0], "edges_g": table.inverse_edges[1]})
    return table


def _colour_table(melanin_blend, illuminant, melanin_max, haemoglobin_max, nodes, inverse_cells, model, direct) -> ColourTable:
    from scipy.spatial import cKDTree

    grid = np.linspace(0.0, 1.0, nodes)
    u, v = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
    box = (float(melanin_blend), float(melanin_max), float(haemoglobin_max))
    weights = jnp.asarray(linear_srgb_weights(COLOUR_WAVELENGTHS_NM, illuminant))
    if not direct:
        value, du, dv, duv = (np.asarray(a).reshape(nodes, nodes, 3) for a in _node_data(jnp.asarray(u), jnp.asarray(v), *box, weights, model))
    else:
        value, du, dv, duv = _interpolated_node_data(grid, np.stack([u, v], axis=-1), *box, weights, model)
    h = 1.0 / (nodes - 1)  # derivatives per unit root -> per unit cell coordinate
    coefficients = _patch_coefficients(value, h * du, h * dv, h * h * duv)

    # inverse warm starts from a finer sampling of the spline (4 samples per cell and axis)
    fine = np.linspace(0.0, 1.0, 4 * (nodes - 1) + 1)
    fine_roots = np.stack([a.ravel() for a in np.meshgrid(fine, fine, indexing="ij")], axis=-1)
    fine_colour = (np.asarray(a) for a in spline_rgb(jnp.asarray(coefficients), jnp.asarray(fine_roots)))
    chroma, chroma_jacobian = _chromaticity_and_jacobian(*fine_colour)
    # Cells of equal sample count along each axis (quantiles): the colour map compresses much of
    # the box into a small patch of chromaticity, which a uniform grid would leave coarse.
    edges = np.quantile(chroma, np.linspace(0.0, 1.0, inverse_cells + 1), axis=0).T  # (2, cells + 1)
    centres = 0.5 * (edges[:, 1:] + edges[:, :-1])
    widths = np.diff(edges, axis=1)
    cell_centres = np.stack(np.meshgrid(*centres, indexing="ij"), axis=-1).reshape(-1, 2)
    reach = 2.0 * np.hypot(*(a.ravel() for a in np.meshgrid(*widths, indexing="ij")))  # two cells
    # First start: the nearest fine sample. Second: among the nodes within two cells in
    # chromaticity, the nearest one far from the first in the roots (or the first again): the fit
    # tries both where they differ and lets the shading decide.
    _, first = cKDTree(chroma).query(cell_centres, workers=-1)
    node_roots = np.stack([u, v], axis=-1)
    distance, near = cKDTree(chromaticity(value.reshape(-1, 3))).query(cell_centres, k=24, workers=-1)
    far = (np.linalg.norm(node_roots[near] - fine_roots[first][:, None], axis=-1) > 0.1) & (distance <= reach[:, None])
    node = near[np.arange(len(near)), np.argmax(far, axis=1)]
    node_in_fine = 4 * (node // nodes) * len(fine) + 4 * (node % nodes)  # nodes are every 4th fine sample
    second = np.where(far.any(axis=1), node_in_fine, first)
    starts = np.stack([first, second], axis=1).reshape(inverse_cells, inverse_cells, 2)
    inverse = [a[starts].astype(np.float32) for a in (fine_roots, chroma, _inverse_2x2(chroma_jacobian))]
    inner_edges = (edges[0, 1:-1].copy(), edges[1, 1:-1].copy())
    blend, c_m_max, c_h_max = box
    return ColourTable(blend, illuminant, c_m_max, c_h_max, nodes, coefficients, *inverse, inner_edges, model)


@jax.jit
def warm_starts(inverse, pixels):
    """Both warm starts (n, 2 branches, 2) for linear sRGB pixels (n, 3) from
    ``ColourTable.device_inverse``: each cell's start moved by the inverse Jacobian of its
    chromaticity towards the pixel's (a Newton step in chromaticity, which the shading does not
    move), by at most ``_AFFINE_REACH`` in the roots."""
    edges_r, edges_g, roots, chroma_at, jacobian = inverse
    total = pixels.sum(axis=-1)
    chroma = pixels[:, :2] / jnp.where(total > 0, total, 1.0)[:, None]
    a, b = jnp.searchsorted(edges_r, chroma[:, 0]), jnp.searchsorted(edges_g, chroma[:, 1])
    offset = chroma[:, None, :] - chroma_at[a, b]  # (n, 2 branches, 2)
    jacobian = jacobian[a, b]
    step = jacobian[..., 0] * offset[..., :1] + jacobian[..., 1] * offset[..., 1:]
    step = step * jnp.minimum(1.0, _AFFINE_REACH / jnp.maximum(jnp.abs(step).max(axis=-1, keepdims=True), 1e-30))
    return jnp.clip(roots[a, b] + step, 0.0, 1.0)


@eqx.filter_jit
def params_rgb(columns, weights, model: SkinModel):
    """Linear sRGB (shading 1) of ``model`` for (C_m, beta_m, C_h) rows (n, 3), with ``weights``
    (3, wavelengths) from ``linear_srgb_weights(COLOUR_WAVELENGTHS_NM, illuminant)``."""
    params = SkinParams(columns[:, 0], columns[:, 1], columns[:, 2])
    return skin_reflectance(params, jnp.asarray(COLOUR_WAVELENGTHS_NM, columns.dtype), model) @ weights.T


@eqx.filter_jit
def model_rgb(roots, melanin_blend, melanin_max, haemoglobin_max, weights, model: SkinModel):
    """Linear sRGB (shading 1) of the forward model at normalised roots (n, 2) in [0, 1].

    Not clipped here: a clip's derivative at the box edge is 1/2 in JAX, which would corrupt the
    spline's edge nodes."""
    c_m = melanin_max * roots[:, 0] ** 2
    c_h = haemoglobin_max * roots[:, 1] ** 2
    return params_rgb(jnp.stack([c_m, jnp.full_like(c_m, melanin_blend), c_h], axis=-1), weights, model)


@eqx.filter_jit
def _node_data(u, v, melanin_blend, melanin_max, haemoglobin_max, weights, model):
    """Colour, d/du, d/dv and d2/dudv at nodes (n,), each (n, 3), by forward-mode autodiff."""

    def colour(u, v):
        return model_rgb(jnp.stack([u, v])[None], melanin_blend, melanin_max, haemoglobin_max, weights, model)[0]

    def with_du(u, v):
        return jax.jvp(lambda x: colour(x, v), (u,), (jnp.ones_like(u),))

    def node(u, v):
        (value, du), (dv, duv) = jax.jvp(lambda y: with_du(u, y), (v,), (jnp.ones_like(v),))
        return value, du, dv, duv

    return jax.vmap(node)(u, v)


def _interpolated_node_data(grid, roots, melanin_blend, melanin_max, haemoglobin_max, weights, model):
    """Colour at the nodes from the model, derivatives from the bicubic interpolating spline
    through them (not-a-knot, SciPy): for the transport model, whose nested forward-mode
    derivatives cost ~11 spectra per node against one for a value (measured)."""
    from scipy.interpolate import RectBivariateSpline


    evaluate = lambda r: (model_rgb(r, melanin_blend, melanin_max, haemoglobin_max, weights, model),)  # noqa: E731
    (value,) = map_batches(evaluate, (roots,), min(len(roots), 256))
    n = len(grid)
    value = value.reshape(n, n, 3)
    splines = [RectBivariateSpline(grid, grid, value[..., c], kx=3, ky=3, s=0) for c in range(3)]
    derivative = lambda dx, dy: np.stack([spl(grid, grid, dx=dx, dy=dy) for spl in splines], axis=-1)  # noqa: E731
    return value, derivative(1, 0), derivative(0, 1), derivative(1, 1)


def _patch_coefficients(value, du, dv, duv) -> np.ndarray:
    """Monomial coefficients (cells^2, 48) of the bicubic Hermite patches; inputs (nodes, nodes, 3)
    with derivatives per unit cell coordinate."""
    corners = lambda a: (a[:-1, :-1], a[1:, :-1], a[:-1, 1:], a[1:, 1:])  # noqa: E731  (00, 10, 01, 11)
    f00, f10, f01, f11 = corners(value)
    a00, a10, a01, a11 = corners(du)
    b00, b10, b01, b11 = corners(dv)
    c00, c10, c01, c11 = corners(duv)
    # rows: along a (p0, p1, d0, d1); columns: along b (p0, p1, d0, d1)
    g = np.stack(
        [
            np.stack([f00, f01, b00, b01], -1),
            np.stack([f10, f11, b10, b11], -1),
            np.stack([a00, a01, c00, c01], -1),
            np.stack([a10, a11, c10, c11], -1),
        ],
        -2,
    )  # (cells, cells, 3, 4, 4)
    coefficients = _HERMITE @ g @ _HERMITE.T  # [p, q] multiplies a^p b^q
    cells = value.shape[0] - 1
    return np.moveaxis(coefficients, 2, -1).reshape(cells * cells, 48)


@jax.jit
def spline_rgb(coefficients, roots):
    """The spline's colour (n, 3) at roots (n, 2) in [0, 1]^2 and its derivatives d/du, d/dv (n, 3)."""
    channels = spline_channels(coefficients, roots[:, 0], roots[:, 1])
    return tuple(jnp.stack([channel[i] for channel in channels], axis=-1) for i in range(3))


def spline_channels(coefficients, u, v, second: bool = False):
    """The spline at roots u, v (n,) in [0, 1], per channel: ((value, d/du, d/dv) of r, of g, of b);
    with ``second``, each channel's tuple also holds (d2/du2, d2/du dv, d2/dv2).

    One channel at a time over columns of the gathered coefficients, Horner in b then in a:
    XLA's CPU backend runs these plain (n,) products several times faster than contractions over
    the tiny (4, 4, 3) axes of a (n, 48) block."""
    cells = int(round(np.sqrt(coefficients.shape[0])))
    x, y = jnp.clip(u, 0.0, 1.0) * cells, jnp.clip(v, 0.0, 1.0) * cells
    i, j = jnp.clip(jnp.floor(x), 0, cells - 1), jnp.clip(jnp.floor(y), 0, cells - 1)
    a, b = x - i, y - j
    c = coefficients[i.astype(jnp.int32) * cells + j.astype(jnp.int32)]  # (n, 48)
    channels = []
    for channel in range(3):
        k = lambda p, q: c[:, 3 * (4 * p + q) + channel]  # noqa: E731  (coefficient of a^p b^q)
        along_b = [k(p, 0) + b * (k(p, 1) + b * (k(p, 2) + b * k(p, 3))) for p in range(4)]
        along_db = [k(p, 1) + b * (2.0 * k(p, 2) + 3.0 * b * k(p, 3)) for p in range(4)]
        value = along_b[0] + a * (along_b[1] + a * (along_b[2] + a * along_b[3]))
        d_u = (along_b[1] + a * (2.0 * along_b[2] + 3.0 * a * along_b[3])) * cells
        d_v = (along_db[0] + a * (along_db[1] + a * (along_db[2] + a * along_db[3]))) * cells
        if not second:
            channels.append((value, d_u, d_v))
            continue
        along_ddb = [2.0 * k(p, 2) + 6.0 * b * k(p, 3) for p in range(4)]
        d_uu = (2.0 * along_b[2] + 6.0 * a * along_b[3]) * cells**2
        d_uv = (along_db[1] + a * (2.0 * along_db[2] + 3.0 * a * along_db[3])) * cells**2
        d_vv = (along_ddb[0] + a * (along_ddb[1] + a * (along_ddb[2] + a * along_ddb[3]))) * cells**2
        channels.append((value, d_u, d_v, d_uu, d_uv, d_vv))
    return tuple(channels)


def _chromaticity_and_jacobian(rgb, d_u, d_v):
    """Chromaticity (n, 2) of colours (n, 3) and its derivatives (n, 2 chroma, 2 roots) from the
    colour's derivatives along the roots."""
    total = rgb.sum(axis=-1, keepdims=True)

    def derivative(d):
        return (d[:, :2] * total - rgb[:, :2] * d.sum(axis=-1, keepdims=True)) / total**2

    return rgb[:, :2] / total, np.stack([derivative(d_u), derivative(d_v)], axis=-1)


def _inverse_2x2(matrices):
    """Inverses of (n, 2, 2) matrices; 0 where singular (no correction is better than a wild one)."""
    det = matrices[:, 0, 0] * matrices[:, 1, 1] - matrices[:, 0, 1] * matrices[:, 1, 0]
    scale = np.abs(matrices).max(axis=(1, 2)) ** 2
    safe = np.abs(det) > 1e-12 * scale
    adjugate = np.stack([np.stack([matrices[:, 1, 1], -matrices[:, 0, 1]], -1), np.stack([-matrices[:, 1, 0], matrices[:, 0, 0]], -1)], -2)
    return np.where(safe[:, None, None], adjugate / np.where(safe, det, 1.0)[:, None, None], 0.0)


def chromaticity(rgb: np.ndarray) -> np.ndarray:
    """(r, g) / (r + g + b) of colours (..., 3); 0 where the sum is not positive."""
    total = rgb.sum(axis=-1, keepdims=True)
    return rgb[..., :2] / np.where(total > 0, total, 1.0)
