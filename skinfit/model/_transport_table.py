"""Two-layer transport reflectance as a tabulated tricubic B-spline: adding-doubling at closed-form cost.

An epidermis (absorption sigma_a1, reduced scattering sigma_s1', thickness d; mm^-1, mm^-1, mm) over
a semi-infinite dermis (sigma_a2, sigma_s2'), both with the same Henyey-Greenstein g and refractive
index n, air above. One-dimensional transport has no length scale of its own within a layer, so
the diffuse reflectance of ``transport.stack_reflectance_transport`` (normal incidence, specular
excluded, entry Fresnel 1 - F0 included) depends on three dimensionless numbers only:

    x1 = log(sigma_a1 / sigma_s1'),  x2 = log(sigma_s1' d),  x3 = log(sigma_a2 / sigma_s2')

(albedo of each layer, reduced optical thickness of the epidermis). The table holds the
reflectance on a regular grid in (x1, x2, x3) over

    sigma_a / sigma_s' in [1e-5, 1e2] (both layers),  sigma_s1' d in [1e-2, 1e2],

as a tensor-product cubic B-spline interpolating the node values (not-a-knot ends, so the error
stays O(h^4) up to the edges), in the transformed value

    y = logit(R / R_max) = log(R / (R_max - R)),   R_max = 1 - F0 = 1 - ((n - 1) / (n + 1))^2

(R_max: the reflectance without absorption, all light that enters comes back). Both tails are
then nearly linear in the log coordinates, log R ~ -x at strong absorption, log(R_max - R) ~ x / 2
at weak (diffusion's sqrt(sigma_a / sigma_s')), and an error in y is a relative error
(1 - R / R_max) in R. Measured on a 65 x 49 x 65 grid while choosing: interpolating R itself
errs by up to 140 % where R is small; log R and logit agree in the worst errors (small R, where
both are log R) and logit has the 20 % lower median.

The default grid has 129 x 97 x 41 nodes (steps 0.126, 0.096, 0.403 in x1, x2, x3: the dermis's
albedo is the smoothest direction, the hard one is the corner of a thin, strongly absorbing
epidermis over a bright dermis, where R falls by orders of magnitude within a few tenths of x2).
Against direct adding-doubling at 1,000 random points off the nodes (measured by
``benchmarks/build_transport_table.py``, results/transport_table.json): skin-like stacks
(sigma_s' 2-40 mm^-1, d 0.02-0.3 mm, sigma_a 0.01-200 mm^-1) median 2.6e-7, p99 1.8e-5, max 6.7e-5
relative; uniform over the box median 1.1e-7, p99 4.7e-5, max 6.7e-4 (at sigma_a1 / sigma_s1' ~ 80,
sigma_s1' d ~ 0.05). File 1.5 MB (float32 coefficients), build 6.5 min on a (shared) 2-core CPU.

Evaluation is a 4 x 4 x 4 stencil of the coefficients, in JAX: jit-, vmap- and grad-able, and the
derivatives are the exact derivatives of the (C^2) interpolant; a 31-wavelength spectrum costs
about 5 us on a 2-core CPU in batches of 64 (value, or value and gradient), against 10-20 ms by
adding-doubling (benchmarks/results/transport_table.json, transport_fit.json).
Outside the box the coordinates are clamped to it: a ratio below 1e-5 (zero absorption included)
is read as 1e-5, above 1e2 as 1e2, and likewise the optical thickness; there the derivative along
the clamped coordinate is zero, and no finite non-negative absorption or thickness and positive
scattering gives NaN or Inf.

Where the epidermis is saturated (deeper than 30 decay lengths of its diffuse field,
``saturation_thickness``) the nodes hold the reflectance at that depth, which the dermis no
longer changes: there the direct solver's start is too coarse (see ``saturation_thickness``).

The shipped table (g 0.8, n 1.4, 16 streams) is package data (``skinfit.spectra``,
``transport_table_g0.80_n1.400.npz``, built by ``python -m benchmarks.build_transport_table``);
other (g, n, streams) are built once and cached on disk (``transport_table``).
"""

from __future__ import annotations

import functools
import importlib.resources
import os
import uuid
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from .._caching import eager_cache
from .._compilation_cache import cache_root
from ._transport import STREAMS, stack_reflectance_transport

#: Range of sigma_a / sigma_s' (both layers) and of the epidermis's sigma_s' d the table covers.
RATIO_RANGE = (1e-5, 1e2)
THICKNESS_RANGE = (1e-2, 1e2)

#: Nodes along (x1, x2, x3) of the shipped table (accuracy: the module docstring).
DEFAULT_NODES = (129, 97, 41)

#: Depth, in decay lengths of the diffuse field, beyond which the epidermis hides the dermis
#: (light returning from it is attenuated by < e^-30 relative to the epidermis's own reflectance).
_SATURATION_DEPTH = 30.0

#: Nodes per adding-doubling batch while building: bounded memory, one compilation.
_BUILD_BATCH = 1024

_SHIPPED = {(0.8, 1.4, STREAMS): "transport_table_g0.80_n1.400.npz"}
_IOR_ABOVE = 1.0  # air
_FORMAT = 1


class TransportTable(eqx.Module):
    """Tricubic B-spline of logit(R / R_max) over (x1, x2, x3) (see the module docstring).

    ``coefficients[i, j, k]`` multiplies the B-spline centred on node (i - 1, j - 1, k - 1): the
    (n1 + 2, n2 + 2, n3 + 2) coefficients of a grid of n1 x n2 x n3 nodes starting at ``lower``
    with spacing ``step``."""

    coefficients: jax.Array
    lower: tuple[float, float, float] = eqx.field(static=True)
    step: tuple[float, float, float] = eqx.field(static=True)
    anisotropy: float = eqx.field(static=True)
    ior: float = eqx.field(static=True)
    streams: int = eqx.field(static=True)
    ior_above: float = eqx.field(static=True, default=_IOR_ABOVE)

    @property
    def nodes(self) -> tuple[int, int, int]:
        return tuple(int(s) - 2 for s in self.coefficients.shape)

    @property
    def upper(self) -> tuple[float, float, float]:
        return tuple(lo + (n - 1) * h for lo, n, h in zip(self.lower, self.nodes, self.step))

    @property
    def max_reflectance(self) -> float:
        """R_max = 1 - F0: the reflectance of the non-absorbing stack."""
        return _max_reflectance(self.ior, self.ior_above)

    @eqx.filter_jit  # one program per shape, also when called eagerly (op by op it compiles dozens)
    def reflectance(self, absorption_epidermis, reduced_scattering_epidermis, thickness_mm, absorption_dermis,
                    reduced_scattering_dermis):
        """Diffuse reflectance (1 - F0) R12 at normal incidence, the convention of
        ``stack_reflectance_transport(..., semi_infinite=True)``; mm^-1, mm^-1, mm, mm^-1, mm^-1.
        The arguments broadcast (any shape); the result has the broadcast shape and the dtype of the
        inputs (float32 in, float32 out). Coordinates outside the table are clamped to it."""
        args = (absorption_epidermis, reduced_scattering_epidermis, thickness_mm, absorption_dermis, reduced_scattering_dermis)
        dtype = jnp.result_type(*args, float)
        sa1, ss1, d, sa2, ss2 = (jnp.asarray(a, dtype) for a in args)
        shape = jnp.broadcast_shapes(*(a.shape for a in (sa1, ss1, d, sa2, ss2)))
        # Clamp the ratios before the logarithm: zero absorption gives log(1e-5) and a zero
        # derivative, where log(0) would give -inf and 0 * inf = NaN in the gradient.
        x1 = jnp.log(jnp.clip(sa1 / ss1, *RATIO_RANGE))
        x2 = jnp.log(jnp.clip(ss1 * d, *THICKNESS_RANGE))
        x3 = jnp.log(jnp.clip(sa2 / ss2, *RATIO_RANGE))
        x = [jnp.broadcast_to(a, shape).reshape(-1) for a in (x1, x2, x3)]
        y = _spline(self.coefficients.astype(dtype), *x, self.lower, self.step)
        return (self.max_reflectance * jax.nn.sigmoid(y)).reshape(shape)


def _max_reflectance(ior: float, ior_above: float = _IOR_ABOVE) -> float:
    """1 - F0 at normal incidence, in plain Python (the indices are static: this runs inside traces)."""
    return 1.0 - ((ior - ior_above) / (ior + ior_above)) ** 2


def _bspline_weights(u):
    """Weights (..., 4) of the four cubic B-splines that are non-zero at u in [0, 1] of a cell."""
    v = 1.0 - u
    u2, u3 = u * u, u * u * u
    return jnp.stack([v * v * v, 3.0 * u3 - 6.0 * u2 + 4.0, -3.0 * u3 + 3.0 * u2 + 3.0 * u + 1.0, u3], axis=-1) / 6.0


def _bspline_slopes(u):
    """d/du of ``_bspline_weights`` (..., 4)."""
    v = 1.0 - u
    u2 = u * u
    return jnp.stack([-3.0 * v * v, 9.0 * u2 - 12.0 * u, -9.0 * u2 + 6.0 * u + 3.0, 3.0 * u2], axis=-1) / 6.0


def _stencil(coefficients, x, lower, step):
    """The 4 x 4 x 4 coefficients around each point (one slice each: on CPU twice as fast as a
    gather of 64 scattered indices at spectrum-sized batches) and, per axis, the position u in
    [0, 1] of the point in its cell."""
    index, position = [], []
    for xi, lo, h, size in zip(x, lower, step, coefficients.shape):
        t = (xi - lo) / h
        cell = jnp.clip(jnp.floor(t), 0, size - 4)  # size - 3 cells: the last node falls in the last cell
        index.append(cell.astype(jnp.int32))
        position.append(t - cell)
    block = jax.vmap(lambda i, j, k: jax.lax.dynamic_slice(coefficients, (i, j, k), (4, 4, 4)))(*index)
    return block, position


def _contract(block, weights):
    """sum_k block[..., k] weights[:, k]: the last axis of a stencil block (m, ..., 4) against
    per-point weights (m, 4). Written as four fused multiply-adds: on CPU, XLA's batched dot for
    these 4-long contractions cost 2.5 times as much (measured: the spline of 512 x 31 points, 2-core
    CPU, 2.5 us per 31 points through einsum, 1.0 unrolled)."""
    shape = (-1,) + (1,) * (block.ndim - 2)
    return sum(block[..., k] * weights[:, k].reshape(shape) for k in range(4))


@functools.partial(jax.custom_jvp, nondiff_argnums=(4, 5))
def _spline(coefficients, x1, x2, x3, lower, step):
    """The spline at the points (x1, x2, x3) (each (m,), inside the grid): the stencil contracted
    with the weights axis by axis."""
    block, u = _stencil(coefficients, (x1, x2, x3), lower, step)
    block = _contract(block, _bspline_weights(u[2]))
    block = _contract(block, _bspline_weights(u[1]))
    return _contract(block, _bspline_weights(u[0]))


@functools.partial(_spline.defjvp, symbolic_zeros=True)
def _spline_jvp(lower, step, primals, tangents):
    # The value and its three partial derivatives from one stencil: a Jacobian (any number of
    # tangents) then costs about two evaluations, where differentiating through the slices and
    # contractions cost ten (measured: jacfwd of a 31-wavelength spectrum in 3 directions, 2-core
    # CPU, 23 us through the contractions against 2.5 us).
    coefficients, *x = primals
    block, u = _stencil(coefficients, x, lower, step)
    weights = [_bspline_weights(ui) for ui in u]
    slopes = [_bspline_slopes(ui) / h for ui, h in zip(u, step)]  # d weights / dx
    c = _contract(block, weights[2])
    dc = _contract(block, slopes[2])
    b = _contract(c, weights[1])
    value = _contract(b, weights[0])
    gradient = (_contract(b, slopes[0]), _contract(_contract(c, slopes[1]), weights[0]),
                _contract(_contract(dc, weights[1]), weights[0]))
    tangent = jnp.zeros_like(value)
    for g, t in zip(gradient, tangents[1:]):
        if not isinstance(t, SymbolicZero):
            tangent = tangent + g * t
    if not isinstance(tangents[0], SymbolicZero):  # the spline is linear in its coefficients
        tangent = tangent + _spline(tangents[0], *x, lower, step)
    return value, tangent


def _not_a_knot_inverse(n: int) -> np.ndarray:
    """(n + 2, n) matrix from values at n equispaced nodes to the coefficients of their cubic
    B-spline interpolant with not-a-knot ends (third derivative continuous at the second and the
    second-last node)."""
    if n < 4:
        raise ValueError(f"a not-a-knot cubic spline needs at least 4 nodes per axis, got {n}")
    system = np.zeros((n + 2, n + 2))
    for j in range(n):
        system[j, j : j + 3] = (1.0, 4.0, 1.0)
    system[:n] /= 6.0
    fourth_difference = (-1.0, 4.0, -6.0, 4.0, -1.0)
    system[n, :5] = fourth_difference
    system[n + 1, -5:] = fourth_difference
    return np.linalg.inv(system)[:, :n]


def spline_coefficients(values: np.ndarray) -> np.ndarray:
    """Coefficients (n1 + 2, n2 + 2, n3 + 2) of the tricubic B-spline interpolating ``values``
    (n1, n2, n3) on a regular grid: one small dense solve per axis (the tensor product)."""
    coefficients = np.asarray(values, dtype=np.float64)
    for axis in range(coefficients.ndim):
        coefficients = np.moveaxis(np.tensordot(_not_a_knot_inverse(coefficients.shape[axis]), coefficients, axes=(1, axis)), 0, axis)
    return coefficients


def grid_axes(nodes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Node coordinates along x1, x2, x3 for ``nodes`` per axis: the box of the module docstring."""
    bounds = (RATIO_RANGE, THICKNESS_RANGE, RATIO_RANGE)
    return tuple(np.linspace(np.log(lo), np.log(hi), int(n)) for (lo, hi), n in zip(bounds, nodes))


def saturation_thickness(x1, anisotropy: float):
    """log of the reduced optical thickness sigma_s1' d beyond which the epidermis of
    x1 = log(sigma_a1 / sigma_s1') is saturated (the dermis no longer shows): _SATURATION_DEPTH
    decay lengths of its deep diffuse field. The decay rate is diffusion's
    mu_eff = sqrt(3 sigma_a (sigma_a + sigma_s')), and at most the extinction sigma_a + sigma_s
    (transport's slowest decay, the unscattered beam's, where diffusion overestimates it).

    The nodes beyond take the value at this thickness: the adding-doubling of a layer starts from
    a slice 2^-13 of its optical depth thick, and at optical depths of hundreds or more (strong
    absorption, sigma_s1' d near 1e2) that start is too coarse: the direct result drifts
    (relative 1e-3 at an optical depth of ~400) and finally overflows to NaN, where the exact
    reflectance no longer changes with d."""
    ratio = np.exp(np.asarray(x1, dtype=float))
    decay = np.minimum(np.sqrt(3.0 * ratio * (1.0 + ratio)), ratio + 1.0 / (1.0 - anisotropy))  # per sigma_s1'
    return np.log(_SATURATION_DEPTH / decay)


def direct_reflectance(coordinates, anisotropy: float, ior: float, streams: int = STREAMS):
    """Adding-doubling reflectance at points (m, 3) of (x1, x2, x3): the stack with sigma_s' = 1
    in both layers (the scale drops out), under jit and vmap."""

    def one(x):
        absorption = jnp.stack([jnp.exp(x[0]), jnp.exp(x[2])])
        thickness = jnp.stack([jnp.exp(x[1]), jnp.ones_like(x[1])])  # the dermis's is ignored
        ones = jnp.ones_like(absorption)
        return stack_reflectance_transport(absorption, ones, thickness, anisotropy * ones, ior=ior, ior_above=_IOR_ABOVE,
                                           semi_infinite=True, streams=streams)

    return jax.vmap(one)(coordinates)


_direct_jit = jax.jit(direct_reflectance, static_argnames=("anisotropy", "ior", "streams"))


def node_reflectance(coordinates: np.ndarray, anisotropy: float, ior: float, streams: int = STREAMS, *,
                     progress: bool = True, batch: int = _BUILD_BATCH) -> np.ndarray:
    """Adding-doubling reflectance (m,) at points (m, 3) of (x1, x2, x3), in fixed-size batches
    (bounded memory; the last is padded, so one compilation serves all)."""
    coordinates = np.asarray(coordinates, dtype=np.float64)
    m = len(coordinates)
    batch = max(1, min(batch, m))
    out = np.empty(m)
    starts = range(0, m, batch)
    if progress:
        from tqdm.auto import tqdm

        starts = tqdm(starts, desc=f"transport table g={anisotropy:g} n={ior:g}", unit="batch")
    for start in starts:
        chunk = coordinates[start : start + batch]
        padded = np.concatenate([chunk, np.repeat(chunk[-1:], batch - len(chunk), axis=0)])
        out[start : start + len(chunk)] = np.asarray(_direct_jit(jnp.asarray(padded), anisotropy=float(anisotropy), ior=float(ior),
                                                                 streams=int(streams)))[: len(chunk)]
    return out


def build_transport_table(anisotropy: float = 0.8, ior: float = 1.4, *, streams: int = STREAMS, nodes=DEFAULT_NODES,
                          progress: bool = True) -> TransportTable:
    """Tabulate the adding-doubling reflectance on ``nodes`` (n1, n2, n3) and fit the spline.

    Costs about 0.6-0.8 ms per node on a 2-core CPU with 16 streams (the default 129 x 97 x 41
    grid: 5-7 min). Nodes where the epidermis is saturated take the value at ``saturation_thickness``."""
    if not -1.0 < anisotropy < 1.0 or ior <= _IOR_ABOVE:
        raise ValueError(f"need -1 < g < 1 and n > 1 (air above), got g={anisotropy}, n={ior}")
    axes = grid_axes(nodes)
    points = np.stack([a.ravel() for a in np.meshgrid(*axes, indexing="ij")], axis=-1)
    points[:, 1] = np.minimum(points[:, 1], saturation_thickness(points[:, 0], anisotropy))
    reflectance = node_reflectance(points, anisotropy, ior, streams, progress=progress)
    r_max = _max_reflectance(ior)
    if not np.all((reflectance > 0.0) & (reflectance < r_max)):
        raise RuntimeError("adding-doubling gave reflectances outside (0, 1 - F0) at table nodes")
    values = np.log(reflectance / (r_max - reflectance)).reshape(tuple(len(a) for a in axes))
    # float32 coefficients (what the file stores, so that a loaded table is the built one): at
    # |y| <~ 15 their rounding moves R by < 1e-6 relative, far below the interpolation error.
    coefficients = spline_coefficients(values).astype(np.float32).astype(np.float64)
    return TransportTable(
        coefficients=jnp.asarray(coefficients),
        lower=tuple(float(a[0]) for a in axes),
        step=tuple(float(a[1] - a[0]) for a in axes),
        anisotropy=float(anisotropy),
        ior=float(ior),
        streams=int(streams),
    )


def save_table(table: TransportTable, path) -> Path:
    """Write ``table`` to a compressed .npz (coefficients as float32, which the builder's are, and
    the metadata); atomic, so that a concurrent reader never sees half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fields = {
        "coefficients": np.asarray(table.coefficients, dtype=np.float32),
        "lower": np.asarray(table.lower), "step": np.asarray(table.step),
        "anisotropy": np.float64(table.anisotropy), "ior": np.float64(table.ior), "ior_above": np.float64(table.ior_above),
        "streams": np.int64(table.streams), "format": np.int64(_FORMAT),
    }
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex}.tmp")  # open(): the umask's permissions
    try:
        with open(temporary, "xb") as file:
            np.savez_compressed(file, **fields)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return path


def load_table(path) -> TransportTable:
    """Read a table written by ``save_table`` (a path or a file-like object)."""
    with np.load(path) as data:
        if int(data["format"]) != _FORMAT:
            raise ValueError(f"transport table format {int(data['format'])}, expected {_FORMAT}")
        # (``transport_table`` caches it through skinfit._caching, which builds outside any trace)
        coefficients = jnp.asarray(np.asarray(data["coefficients"], dtype=np.float64))
        return TransportTable(
            coefficients=coefficients,
            lower=tuple(float(v) for v in data["lower"]),
            step=tuple(float(v) for v in data["step"]),
            anisotropy=float(data["anisotropy"]),
            ior=float(data["ior"]),
            streams=int(data["streams"]),
            ior_above=float(data["ior_above"]),
        )


def cache_dir() -> Path:
    """Where built tables are kept: ``transport/`` in skinfit's cache folder (``$SKINFIT_CACHE_DIR``, else
    ``$XDG_CACHE_HOME/skinfit``, else ``~/.cache/skinfit``)."""
    return cache_root() / "transport"


def _matches(table: TransportTable, anisotropy, ior, streams, nodes) -> bool:
    same_box = np.allclose(table.lower, [a[0] for a in grid_axes(nodes)]) and np.allclose(table.upper, [a[-1] for a in grid_axes(nodes)])
    return (table.anisotropy, table.ior, table.streams, table.nodes) == (anisotropy, ior, streams, tuple(nodes)) and same_box


@eager_cache()
def transport_table(anisotropy: float = 0.8, ior: float = 1.4, *, streams: int = STREAMS, nodes: tuple | None = None,
                    progress: bool = True) -> TransportTable:
    """The table for (g, n, streams): the shipped one for (0.8, 1.4, 16) from the package data
    (``skinfit.spectra``, 'transport_table_g0.80_n1.400.npz'); other values loaded from the cache
    directory (``cache_dir()``) or built (minutes) and saved there. ``nodes`` (a tuple) overrides
    ``DEFAULT_NODES`` (then never the shipped table). Cached in memory per arguments."""
    anisotropy, ior, streams = float(anisotropy), float(ior), int(streams)
    nodes = DEFAULT_NODES if nodes is None else tuple(int(n) for n in nodes)
    shipped = _SHIPPED.get((anisotropy, ior, streams))
    if shipped is not None and nodes == DEFAULT_NODES:
        with importlib.resources.files("skinfit.spectra").joinpath(shipped).open("rb") as file:
            table = load_table(file)
        if (table.anisotropy, table.ior, table.streams) != (anisotropy, ior, streams):
            raise ValueError(f"the shipped {shipped} holds g={table.anisotropy}, n={table.ior}, streams={table.streams}")
        return table
    name = f"transport_table_g{anisotropy!r}_n{ior!r}_s{streams}_nodes{'x'.join(map(str, nodes))}.npz"
    path = cache_dir() / name
    if path.exists():
        try:
            table = load_table(path)
            if _matches(table, anisotropy, ior, streams, nodes):
                return table
        except (OSError, ValueError, KeyError):
            pass  # unreadable or stale: rebuild over it
    table = build_transport_table(anisotropy, ior, streams=streams, nodes=nodes, progress=progress)
    save_table(table, path)
    return table
