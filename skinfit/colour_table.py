"""The skin model's colour over (melanin, haemoglobin) as a bicubic spline, and its inverse.

With the melanin blend fixed for an image, the model's linear sRGB (shading 1) is a smooth function
of two variables. It is tabulated on a grid in the normalised roots

    u = sqrt(C_m / melanin_max),  v = sqrt(C_h / haemoglobin_max),  (u, v) in [0, 1]^2

(square roots spread the nodes where the colour changes fastest, near zero; the colour is smooth
in them since it is smooth in C_m and C_h). Each node stores the exact colour and its exact first
and mixed derivatives (forward-mode autodiff of the model), and each cell holds the bicubic
Hermite patch through its four corners: C^1 across cells, interpolation error O(h^4). On the
default 129 x 129 grid the spline matches the model to ~1e-9 in linear sRGB (measured in
``tests/test_colour_table.py``), far below 16-bit quantisation, at the cost of a few hundred flops
per evaluation instead of the ~31-wavelength model.

The inverse: a grid over chromaticity (r, g) / (r + g + b) stores, per cell, two warm starts (u, v):
the table node of nearest chromaticity and the nearest one on another branch of the fold (the
colour map folds over: with the shading free, (C_m 0.057, C_h 0.074, shading 0.75) and
(0.0175, 0.0067, 0.374) look the same).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

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
    infinity).
    """

    melanin_blend: float
    illuminant: str
    melanin_max: float
    haemoglobin_max: float
    nodes: int
    coefficients: np.ndarray  # (cells^2, 48)
    inverse_roots: np.ndarray  # (inverse_cells, inverse_cells, 2 branches, 2)
    inverse_edges: tuple[np.ndarray, np.ndarray]

    def warm_starts(self, pixels: np.ndarray) -> np.ndarray:
        """Both warm starts (n, 2 branches, 2) for linear sRGB pixels (n, 3)."""
        chroma = chromaticity(pixels)
        a = np.searchsorted(self.inverse_edges[0], chroma[:, 0])
        b = np.searchsorted(self.inverse_edges[1], chroma[:, 1])
        return self.inverse_roots[a, b]

    def model_arguments(self):
        """(melanin_blend, melanin_max, haemoglobin_max, weights): what ``model_rgb`` needs after
        the roots to evaluate the exact model this table interpolates."""
        weights = jnp.asarray(linear_srgb_weights(COLOUR_WAVELENGTHS_NM, self.illuminant))
        return self.melanin_blend, self.melanin_max, self.haemoglobin_max, weights

    def parameters(self, roots):
        """(C_m, C_h) of normalised roots (..., 2)."""
        roots = np.clip(np.asarray(roots, dtype=float), 0.0, 1.0)
        return self.melanin_max * roots[..., 0] ** 2, self.haemoglobin_max * roots[..., 1] ** 2


@functools.lru_cache(maxsize=8)
def colour_table(
    melanin_blend: float = 0.7,
    illuminant: str = DEFAULT_ILLUMINANT,
    melanin_max: float = MELANIN_MAX,
    haemoglobin_max: float = HAEMOGLOBIN_MAX,
    nodes: int = 129,
    inverse_cells: int = 512,
) -> ColourTable:
    """Build (and cache per blend, illuminant, box and size) the colour spline and its inverse."""
    from scipy.spatial import cKDTree

    if not 0.0 <= melanin_blend <= 1.0:
        raise SkinfitInputError(f"melanin_blend must be within [0, 1], got {melanin_blend}")
    grid = np.linspace(0.0, 1.0, nodes)
    u, v = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
    model = (float(melanin_blend), float(melanin_max), float(haemoglobin_max))
    weights = jnp.asarray(linear_srgb_weights(COLOUR_WAVELENGTHS_NM, illuminant))
    value, du, dv, duv = (np.asarray(a).reshape(nodes, nodes, 3) for a in _node_data(jnp.asarray(u), jnp.asarray(v), *model, weights))
    h = 1.0 / (nodes - 1)  # derivatives per unit root -> per unit cell coordinate
    coefficients = _patch_coefficients(value, h * du, h * dv, h * h * duv)

    # inverse warm starts from a finer sampling of the spline (4 samples per cell and axis)
    fine = np.linspace(0.0, 1.0, 4 * (nodes - 1) + 1)
    fine_roots = np.stack([a.ravel() for a in np.meshgrid(fine, fine, indexing="ij")], axis=-1)
    fine_rgb = np.asarray(spline_rgb(jnp.asarray(coefficients), jnp.asarray(fine_roots))[0])
    chroma = chromaticity(fine_rgb)
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
    _, nearest = cKDTree(chroma).query(cell_centres, workers=-1)
    first = fine_roots[nearest]
    node_roots = np.stack([u, v], axis=-1)
    distance, near = cKDTree(chromaticity(value.reshape(-1, 3))).query(cell_centres, k=24, workers=-1)
    far = (np.linalg.norm(node_roots[near] - first[:, None], axis=-1) > 0.1) & (distance <= reach[:, None])
    second = np.where(far.any(axis=1)[:, None], node_roots[near[np.arange(len(near)), np.argmax(far, axis=1)]], first)
    inverse = np.stack([first, second], axis=1).reshape(inverse_cells, inverse_cells, 2, 2)
    inner_edges = (edges[0, 1:-1].copy(), edges[1, 1:-1].copy())
    blend, c_m_max, c_h_max = model
    return ColourTable(blend, illuminant, c_m_max, c_h_max, nodes, coefficients, inverse, inner_edges)


@jax.jit
def params_rgb(columns, weights):
    """Linear sRGB (shading 1) of the forward model for (C_m, beta_m, C_h) rows (n, 3), with
    ``weights`` (3, wavelengths) from ``linear_srgb_weights(COLOUR_WAVELENGTHS_NM, illuminant)``."""
    params = SkinParams(columns[:, 0], columns[:, 1], columns[:, 2])
    return diffuse_reflectance(params, COLOUR_WAVELENGTHS_NM) @ weights.T


@jax.jit
def model_rgb(roots, melanin_blend, melanin_max, haemoglobin_max, weights):
    """Linear sRGB (shading 1) of the forward model at normalised roots (n, 2) in [0, 1].

    Not clipped here: a clip's derivative at the box edge is 1/2 in JAX, which would corrupt the
    spline's edge nodes."""
    c_m = melanin_max * roots[:, 0] ** 2
    c_h = haemoglobin_max * roots[:, 1] ** 2
    return params_rgb(jnp.stack([c_m, jnp.full_like(c_m, melanin_blend), c_h], axis=-1), weights)


@jax.jit
def _node_data(u, v, melanin_blend, melanin_max, haemoglobin_max, weights):
    """Colour, d/du, d/dv and d2/dudv at nodes (n,), each (n, 3), by forward-mode autodiff."""

    def colour(u, v):
        return model_rgb(jnp.stack([u, v])[None], melanin_blend, melanin_max, haemoglobin_max, weights)[0]

    def with_du(u, v):
        return jax.jvp(lambda x: colour(x, v), (u,), (jnp.ones_like(u),))

    def node(u, v):
        (value, du), (dv, duv) = jax.jvp(lambda y: with_du(u, y), (v,), (jnp.ones_like(v),))
        return value, du, dv, duv

    return jax.vmap(node)(u, v)


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


def spline_rgb(coefficients, roots):
    """The spline's colour (n, 3) at roots (n, 2) in [0, 1]^2 and its derivatives d/du, d/dv (n, 3)."""
    cells = int(round(np.sqrt(coefficients.shape[0])))
    x = jnp.clip(roots, 0.0, 1.0) * cells
    cell = jnp.clip(jnp.floor(x), 0, cells - 1)
    a, b = x[:, 0] - cell[:, 0], x[:, 1] - cell[:, 1]
    index = cell[:, 0].astype(jnp.int32) * cells + cell[:, 1].astype(jnp.int32)
    c = coefficients[index].reshape(-1, 4, 4, 3)  # [n, p, q, channel]
    # Horner in b (value and slope), then in a; plain products, which XLA's CPU backend runs far
    # faster than batched contractions of these tiny shapes (and pixel-first: a channel-first
    # layout measured 3x slower)
    b_, a_ = b[:, None, None], a[:, None]
    along_b = c[:, :, 0] + b_ * (c[:, :, 1] + b_ * (c[:, :, 2] + b_ * c[:, :, 3]))  # (n, p, channel)
    along_db = c[:, :, 1] + b_ * (2.0 * c[:, :, 2] + 3.0 * b_ * c[:, :, 3])
    value = along_b[:, 0] + a_ * (along_b[:, 1] + a_ * (along_b[:, 2] + a_ * along_b[:, 3]))
    d_u = (along_b[:, 1] + a_ * (2.0 * along_b[:, 2] + 3.0 * a_ * along_b[:, 3])) * cells
    d_v = (along_db[:, 0] + a_ * (along_db[:, 1] + a_ * (along_db[:, 2] + a_ * along_db[:, 3]))) * cells
    return value, d_u, d_v


def chromaticity(rgb: np.ndarray) -> np.ndarray:
    """(r, g) / (r + g + b) of colours (..., 3); 0 where the sum is not positive."""
    total = rgb.sum(axis=-1, keepdims=True)
    return rgb[..., :2] / np.where(total > 0, total, 1.0)
