"""Transport-exact diffuse reflectance of a layered slab: adding-doubling in JAX.

The azimuthally averaged (m = 0) radiative transfer of a stack of homogeneous layers is solved by
adding-doubling (van de Hulst; Prahl) on a double-Gauss quadrature of ``streams`` directions per
hemisphere, for a pencil beam at normal incidence. Written in photon-probability form: a layer
is a pair of matrices R[i, j], T[i, j], the probabilities that a photon entering in direction j
leaves in direction i (reflected or transmitted); the beam direction (mu = 1) is one more input
direction that nothing scatters into.

- Phase function: Henyey-Greenstein with the layer's ``anisotropy`` g, expanded in Legendre
  polynomials up to 2 x streams with delta-M truncation (Wiscombe 1977): f = g^(2 streams) of the
  forward peak becomes unscattered light, albedo and optical depth are scaled accordingly. The
  expansion is exact for the quadrature, so a non-absorbing layer conserves energy to rounding.
- Scattering coefficient = reduced_scattering / (1 - g): the diffusion model's input stays the
  input.
- A thin layer of optical depth delta starts from the first-order generator (R = delta Gamma_R,
  T = I - delta Gamma_T) and is doubled to the layer's depth; the start's first-order error is
  removed by Richardson extrapolation between delta and delta / 2. A semi-infinite layer is
  doubled to 2^26 optical depths (reflectance within 1e-6 of deeper doubling for skin).
- Boundaries: all layers share one refractive index (skin); the top face sees ``ior_above``:
  the beam enters with 1 - F0, light inside reflects with the exact Fresnel factor of its
  direction (total internal reflection beyond the critical angle) and escapes with the rest.

The result follows the diffusion convention: diffuse reflectance, specular excluded, entry
Fresnel included. Differentiable, jit- and vmap-able; float32 inputs give float32 results, computed
in float64 (the doubling's thin starting layer needs it).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._caching import eager_cache
from .._validate import SkinfitInputError, is_concrete
from ._fresnel import fresnel_reflectance

STREAMS = 16
_FINITE_DOUBLINGS = 12
#: A finite layer deeper than this many diffusion decay lengths is treated as that deep (opaque).
_OPAQUE_DEPTHS = 72.0
_SEMI_INFINITE_START = 2.0**-10
_SEMI_INFINITE_DOUBLINGS = 36


@eager_cache(maxsize=16)
def _quadrature(streams: int, critical_cosine: float = 0.0):
    """Nodes on (0, 1) per hemisphere, the beam direction appended (weight 0), Legendre values.

    Gauss on (0, 1), or, with a critical angle, Gauss on (0, mu_c) and on (mu_c, 1) separately:
    the Fresnel factor has a kink at mu_c that a single Gauss rule integrates only to first order
    in the number of streams (Prahl's adding-doubling splits there too)."""
    x, w = np.polynomial.legendre.leggauss(streams)
    if critical_cosine > 0.0:
        low, high = streams // 2, streams - streams // 2
        xl, wl = np.polynomial.legendre.leggauss(low)
        xh, wh = np.polynomial.legendre.leggauss(high)
        c = critical_cosine
        nodes = np.concatenate([0.5 * c * (xl + 1.0), c + 0.5 * (1.0 - c) * (xh + 1.0)])
        weights = np.concatenate([0.5 * c * wl, 0.5 * (1.0 - c) * wh])
    else:
        nodes, weights = 0.5 * (x + 1.0), 0.5 * w
    mu = np.concatenate([nodes, [1.0]])
    weight = np.concatenate([weights, [0.0]])
    order = 2 * streams
    legendre = np.zeros((order, mu.size))
    legendre[0] = 1.0
    legendre[1] = mu
    for n in range(1, order - 1):
        legendre[n + 1] = ((2 * n + 1) * mu * legendre[n] - n * legendre[n - 1]) / (n + 1)
    return mu, weight, legendre


def _generators(albedo, anisotropy, streams, critical_cosine):
    """delta-M scaled albedo, depth factor and the thin-layer generators Gamma_R, Gamma_T."""
    mu, weight, legendre = (jnp.asarray(a, albedo.dtype) for a in _quadrature(streams, critical_cosine))
    order = legendre.shape[0]
    l = jnp.arange(order, dtype=albedo.dtype)
    g = anisotropy
    f = g**order
    moments = (g ** l - f) / (1.0 - f)
    coef = (2.0 * l + 1.0) / 2.0 * moments
    same = jnp.einsum("l,li,lj->ij", coef, legendre, legendre)  # density in mu_i of photons from mu_j, same hemisphere
    opposite = jnp.einsum("l,li,lj->ij", coef * (-1.0) ** l, legendre, legendre)
    # A split rule integrates the expansion only approximately: renormalise each incoming
    # direction so that a scattered photon goes somewhere (energy conservation to rounding).
    total = (same + opposite).T @ weight
    same, opposite = same / total[None, :], opposite / total[None, :]
    scaled_albedo = albedo * (1.0 - f) / (1.0 - albedo * f)
    depth_factor = 1.0 - albedo * f
    inv_mu = 1.0 / mu
    gamma_r = scaled_albedo * opposite * weight[:, None] * inv_mu[None, :]
    gamma_t = jnp.diag(inv_mu) - scaled_albedo * same * weight[:, None] * inv_mu[None, :]
    return gamma_r, gamma_t, depth_factor


def solve_dominant(a, b):
    """a^-1 b by Gauss-Jordan elimination without pivoting, in plain array operations.

    Every system here is I - M with M a product of reflection operators, whose columns (photon
    probabilities) sum to less than one: column diagonally dominant, so elimination without
    pivoting is stable. Unlike a LAPACK solve it is, under vmap, one batched array program; and
    XLA's CPU runtime was seen to hang (idle, every worker waiting) on LAPACK solves inside the
    doubling loops of batched transport Jacobians."""
    n = a.shape[-1]
    augmented = jnp.concatenate([a, b], axis=-1)

    def eliminate(k, m):
        row = jax.lax.dynamic_index_in_dim(m, k, axis=0, keepdims=False)
        row = row / row[k]
        column = jax.lax.dynamic_index_in_dim(m, k, axis=1, keepdims=False)
        m = m - column[:, None] * row[None, :]
        return jax.lax.dynamic_update_index_in_dim(m, row, k, axis=0)

    return jax.lax.fori_loop(0, n, eliminate, augmented)[:, n:]


def _double(r, t, times):
    eye = jnp.eye(r.shape[-1], dtype=r.dtype)

    def step(_, rt):
        r, t = rt
        x = solve_dominant(eye - r @ r, t)  # (I - R R)^-1 T
        return r + t @ r @ x, t @ x

    return jax.lax.fori_loop(0, times, step, (r, t))


def _layer(gamma_r, gamma_t, delta, doublings):
    eye = jnp.eye(gamma_r.shape[-1], dtype=gamma_r.dtype)
    return _double(delta * gamma_r, eye - delta * gamma_t, doublings)


def _extrapolated(gamma_r, gamma_t, depth, doublings):
    """R, T of a layer of optical depth ``depth``: Richardson between start depths delta, delta/2."""
    coarse = _layer(gamma_r, gamma_t, depth / 2.0**doublings, doublings)
    fine = _layer(gamma_r, gamma_t, depth / 2.0 ** (doublings + 1), doublings + 1)
    return tuple(2.0 * b - a for a, b in zip(coarse, fine))


def _semi_infinite(gamma_r, gamma_t):
    """R of a layer doubled to 2^26 optical depths, Richardson between the two start depths."""
    coarse = _layer(gamma_r, gamma_t, _SEMI_INFINITE_START, _SEMI_INFINITE_DOUBLINGS)[0]
    fine = _layer(gamma_r, gamma_t, _SEMI_INFINITE_START / 2.0, _SEMI_INFINITE_DOUBLINGS + 1)[0]
    return 2.0 * fine - coarse


def critical_cosine(ior: float, ior_above: float) -> float:
    """Cosine (inside) of the critical angle of the top face; 0 when there is none."""
    return float(np.sqrt(1.0 - (ior_above / ior) ** 2)) if ior > ior_above else 0.0


@functools.partial(jax.jit, static_argnames=("ior", "ior_above", "semi_infinite", "streams"))
def stack_reflectance_transport(absorption, reduced_scattering, thickness, anisotropy, *, ior: float, ior_above: float,
                                semi_infinite: bool, streams: int = STREAMS):
    """Diffuse reflectance of one stack from 1-D arrays over its layers (top first; mm^-1, mm^-1,
    mm, g); ``semi_infinite``: the last layer has no bottom (its thickness is ignored); one index
    ``ior`` for the whole stack, ``ior_above`` over it. A finite bottom layer exits into a medium
    of the same index."""
    out_dtype = jnp.result_type(absorption, reduced_scattering, float)
    # The doubling starts from a layer 2^-13 of the optical depth thick, whose 1 - delta/mu float32
    # cannot resolve: the computation runs in float64 whatever the inputs, the result in theirs.
    dtype = jnp.float64
    absorption, reduced_scattering, thickness, anisotropy = (jnp.asarray(a, dtype) for a in (absorption, reduced_scattering, thickness, anisotropy))
    cosine = critical_cosine(ior, ior_above)
    scattering = reduced_scattering / (1.0 - anisotropy)
    extinction = absorption + scattering
    albedo = scattering / extinction
    n_layers = absorption.shape[0]
    eye = jnp.eye(streams + 1, dtype=dtype)

    below = None  # reflection operator of everything below the current layer
    for k in reversed(range(n_layers)):
        gamma_r, gamma_t, depth_factor = _generators(albedo[k], anisotropy[k], streams, cosine)
        if k == n_layers - 1 and semi_infinite:
            below = _semi_infinite(gamma_r, gamma_t)
            continue
        depth = extinction[k] * jnp.where(jnp.isfinite(thickness[k]), thickness[k], 1.0) * depth_factor
        # A layer beyond ~40 of its slowest decay lengths is opaque: nothing crosses it, and the
        # doubling, which starts from depth 2^-13, needs that start thin. The decay rate per optical
        # depth is at least min(1, sqrt(3 (1 - a)(1 - a g))) / 1.75; cap the depth at 72 over the
        # diffusion estimate (its square, floored, keeps gradients finite at a = 1).
        decay_squared = 3.0 * (1.0 - albedo[k]) * (1.0 - albedo[k] * anisotropy[k])
        depth = jnp.minimum(depth, _OPAQUE_DEPTHS * jax.lax.rsqrt(jnp.maximum(decay_squared, 1e-12)))
        r, t = _extrapolated(gamma_r, gamma_t, depth, _FINITE_DOUBLINGS)
        below = r if below is None else r + t @ solve_dominant(eye - below @ r, below @ t)

    mu = jnp.asarray(_quadrature(streams, cosine)[0], dtype)
    fresnel = fresnel_reflectance(mu, jnp.asarray(ior, dtype), jnp.asarray(ior_above, dtype)).at[-1].set(0.0)  # nothing travels up along the beam
    entry = 1.0 - ((ior - ior_above) / (ior + ior_above)) ** 2
    upward = solve_dominant(eye - below * fresnel[None, :], (below[:, -1] * entry)[:, None])[:, 0]
    return jnp.sum((1.0 - fresnel) * upward).astype(out_dtype)


def transport_reflectance(layers, *, ior_above: float = 1.0, streams: int = STREAMS, ior: float | None = None,
                          semi_infinite: bool | None = None):
    """Diffuse reflectance of a stack of ``skinfit.model.Layer`` (top first; fields broadcast, e.g. over
    wavelengths) by adding-doubling; the shape of the broadcast fields. Every layer must have the
    same concrete ``ior`` (or give it as ``ior``, which then overrides the layers', e.g. under
    jit); ``anisotropy`` is each layer's g. ``semi_infinite`` likewise overrides reading the bottom
    layer's thickness (which must otherwise be concrete)."""
    if ior is not None:
        values = np.array([float(ior)])
    else:
        iors = [layer.ior for layer in layers]
        if not all(is_concrete(n) for n in iors):
            raise SkinfitInputError("method='transport' needs concrete refractive indices (not traced)")
        values = np.unique(np.concatenate([np.ravel(np.asarray(n, dtype=float)) for n in iors]))
        if values.size != 1:
            raise SkinfitInputError("method='transport' needs one refractive index for the whole stack")
    if semi_infinite is None:
        if not is_concrete(layers[-1].thickness):
            raise SkinfitInputError("method='transport' needs the bottom layer's thickness as a concrete value")
        bottom = np.asarray(layers[-1].thickness, dtype=float)
        semi_infinite = bool(np.all(np.isinf(bottom)))
        if np.any(np.isinf(bottom)) and not semi_infinite:
            raise SkinfitInputError("the bottom layer must be semi-infinite everywhere or nowhere")
    fields = [[layer.absorption, layer.reduced_scattering, layer.thickness, layer.anisotropy] for layer in layers]
    shape = jnp.broadcast_shapes(*(jnp.shape(f) for row in fields for f in row))
    dtype = jnp.result_type(*(f for row in fields for f in row), float)
    stacked = [jnp.stack([jnp.broadcast_to(jnp.asarray(row[i], dtype), shape) for row in fields], axis=-1).reshape(-1, len(layers))
               for i in range(4)]
    one = functools.partial(stack_reflectance_transport, ior=float(values[0]), ior_above=float(ior_above),
                            semi_infinite=semi_infinite, streams=int(streams))
    return jax.vmap(one)(*stacked).reshape(shape)
