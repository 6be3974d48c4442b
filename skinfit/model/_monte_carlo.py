"""A small Monte Carlo of light in a layered slab: the exact-transport check for users and tests.

MCML-style (Wang, Jacques & Zheng 1995), written for NumPy and vectorised over photons: a pencil
beam at normal incidence, Henyey-Greenstein scattering with each layer's ``anisotropy`` g (the
layer's reduced scattering is the input, scattering = reduced_scattering / (1 - g)), Fresnel
reflection at every boundary between different indices (unpolarised, exact), implicit capture
(absorption reduces the photon weight) and Russian roulette below ``ROULETTE_WEIGHT``. The
random numbers come from NumPy's PCG64 (53-bit doubles: MCML's single-precision generator biases
results at g = 0.8, model notes 12).

The result has the same convention as ``layered_reflectance``: diffuse reflectance at normal
incidence with the specular reflection excluded and the entry Fresnel transmittance included,
with its standard error from the spread over batches. With ``radii_mm`` it is also resolved in
radius: the reflectance that leaves the top within each distance of the beam (the energy within
r, 2 pi int_0^r R(r') r' dr'), the radially resolved reference for profiles.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from .._validate import SkinfitInputError
from ._layers import Layer

ROULETTE_WEIGHT = 1e-4
ROULETTE_SURVIVAL = 0.1


@dataclasses.dataclass(frozen=True)
class MonteCarloResult:
    """Diffuse reflectance and transmittance of a stack, with standard errors (MC statistics).

    ``radii_mm`` (k,), ``reflectance_within`` (k,) and its ``reflectance_within_error`` (k,): the
    reflectance leaving the top within each radius of the beam (empty unless radii were asked for).
    """

    reflectance: float
    reflectance_error: float
    transmittance: float
    transmittance_error: float
    photons: int
    radii_mm: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    reflectance_within: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    reflectance_within_error: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))


def _fresnel(cos_i, n_from, n_to):
    """Unpolarised Fresnel reflectance for light going from index n_from into n_to (cos_i > 0)."""
    ratio = n_from / n_to
    sin_t2 = ratio**2 * (1.0 - cos_i**2)
    total = sin_t2 >= 1.0
    cos_t = np.sqrt(np.maximum(1.0 - sin_t2, 0.0))
    rs = ((n_from * cos_i - n_to * cos_t) / (n_from * cos_i + n_to * cos_t)) ** 2
    rp = ((n_from * cos_t - n_to * cos_i) / (n_from * cos_t + n_to * cos_i)) ** 2
    return np.where(total, 1.0, 0.5 * (rs + rp)), cos_t


def _scatter(ux, uy, uz, g, rng):
    """New directions after a Henyey-Greenstein scattering (vectorised MCML update)."""
    xi = rng.random(ux.shape)
    safe_g = np.where(np.abs(g) < 1e-6, 1.0, g)
    tmp = (1 - g**2) / (1 - g + 2 * g * xi)
    cos_t = np.where(np.abs(g) < 1e-6, 2 * xi - 1, (1 + g**2 - tmp**2) / (2 * safe_g))
    cos_t = np.clip(cos_t, -1.0, 1.0)
    sin_t = np.sqrt(1 - cos_t**2)
    phi = 2 * np.pi * rng.random(ux.shape)
    cos_p, sin_p = np.cos(phi), np.sin(phi)
    near_pole = np.abs(uz) > 0.99999
    denom = np.sqrt(np.maximum(1 - uz**2, 1e-300))
    nx = sin_t * (ux * uz * cos_p - uy * sin_p) / denom + ux * cos_t
    ny = sin_t * (uy * uz * cos_p + ux * sin_p) / denom + uy * cos_t
    nz = -sin_t * cos_p * denom + uz * cos_t
    px, py, pz = sin_t * cos_p, sin_t * sin_p, np.sign(uz) * cos_t
    return np.where(near_pole, px, nx), np.where(near_pole, py, ny), np.where(near_pole, pz, nz)


def monte_carlo_reflectance(
    layers: Sequence[Layer],
    *,
    photons: int = 200_000,
    seed: int = 0,
    ior_above: float = 1.0,
    ior_below: float = 1.0,
    batches: int = 10,
    radii_mm: Sequence[float] | np.ndarray | None = None,
) -> MonteCarloResult:
    """Diffuse reflectance (and transmittance) of ``layers`` (top first, scalar fields, mm and
    mm^-1; the last may be semi-infinite) for a normally incident pencil beam, by Monte Carlo;
    with ``radii_mm`` (increasing, > 0) also the reflectance within each radius of the beam."""
    if isinstance(layers, Layer):
        layers = [layers]
    layers = list(layers)
    if not layers or not all(isinstance(layer, Layer) for layer in layers):
        raise SkinfitInputError("layers must be a non-empty sequence of skinfit.model.Layer, top first")
    props = np.array([[float(np.asarray(getattr(layer, f)).reshape(())) for f in ("absorption", "reduced_scattering", "thickness", "ior", "anisotropy")]
                      for layer in layers])
    if np.any(np.isinf(props[:-1, 2])):
        raise SkinfitInputError("only the bottom layer may be semi-infinite")
    if photons < batches or batches < 2:
        raise SkinfitInputError("need photons >= batches >= 2")
    radii = np.zeros(0) if radii_mm is None else np.asarray(radii_mm, dtype=float).reshape(-1)
    if radii.size and not (np.all(np.isfinite(radii)) and radii[0] > 0 and np.all(np.diff(radii) > 0)):
        raise SkinfitInputError("radii_mm must be finite, positive and increasing")
    absorption, reduced, thickness, ior, g = props.T
    scattering = reduced / (1 - g)
    extinction = absorption + scattering
    tops = np.concatenate([[0.0], np.cumsum(thickness)[:-1]])
    bottoms = np.cumsum(thickness)
    n_index = np.concatenate([[ior_above], ior, [ior_below]])  # n_index[k + 1] is layer k
    rng = np.random.default_rng(seed)
    per_batch = photons // batches
    reflected, transmitted = np.zeros(batches), np.zeros(batches)
    within = np.zeros((batches, radii.size))
    entry = 1.0 - ((ior[0] - ior_above) / (ior[0] + ior_above)) ** 2
    for b in range(batches):
        r, t, w = _run_batch(per_batch, rng, absorption, scattering, extinction, g, tops, bottoms, n_index, radii)
        reflected[b], transmitted[b], within[b] = entry * r / per_batch, entry * t / per_batch, entry * w / per_batch
    se = lambda x: np.std(x, ddof=1, axis=0) / np.sqrt(batches)  # noqa: E731
    return MonteCarloResult(float(reflected.mean()), float(se(reflected)), float(transmitted.mean()), float(se(transmitted)),
                            per_batch * batches, radii, within.mean(axis=0), se(within))


def _run_batch(n, rng, absorption, scattering, extinction, g, tops, bottoms, n_index, radii):
    """Total escaping weight through the top and the bottom for n photons (each entering with
    weight 1 just below the top surface, heading straight down), and the weight escaping through
    the top within each of ``radii`` of the entry point."""
    x, y, z = np.zeros(n), np.zeros(n), np.zeros(n)
    within = np.zeros(radii.size)
    ux, uy, uz = np.zeros(n), np.zeros(n), np.ones(n)
    weight = np.ones(n)
    layer = np.zeros(n, dtype=int)
    reflected = transmitted = 0.0
    optical = np.zeros(n)  # remaining dimensionless step (0: draw a new one)
    n_layers = len(tops)
    while n:
        fresh = optical <= 0
        optical[fresh] = -np.log(rng.random(int(fresh.sum())) + 1e-300)
        sigma_t = extinction[layer]
        # distance to the boundary along the direction
        to_boundary = np.where(uz > 0, (bottoms[layer] - z) / np.maximum(uz, 1e-300),
                               np.where(uz < 0, (tops[layer] - z) / np.minimum(uz, -1e-300), np.inf))
        step = optical / sigma_t
        hits = step >= to_boundary
        # photons that stay inside: move, deposit, scatter
        inside = ~hits
        if radii.size:
            x[inside] += step[inside] * ux[inside]
            y[inside] += step[inside] * uy[inside]
        z[inside] += step[inside] * uz[inside]
        optical[inside] = 0.0
        keep = scattering[layer[inside]] / sigma_t[inside]
        weight[inside] *= keep
        ux[inside], uy[inside], uz[inside] = _scatter(ux[inside], uy[inside], uz[inside], g[layer[inside]], rng)
        # photons that reach a boundary: move there, keep the rest of the step, reflect or cross
        if hits.any():
            h = np.flatnonzero(hits)
            d = to_boundary[h]
            optical[h] -= d * sigma_t[h]
            if radii.size:
                x[h] += d * ux[h]
                y[h] += d * uy[h]
            down = uz[h] > 0
            z[h] = np.where(down, bottoms[layer[h]], tops[layer[h]])
            next_layer = layer[h] + np.where(down, 1, -1)
            n_from = n_index[layer[h] + 1]
            n_to = n_index[next_layer + 1]
            cos_i = np.abs(uz[h])
            reflect, cos_t = _fresnel(cos_i, n_from, n_to)
            bounce = rng.random(h.size) < reflect
            # reflected: mirror; transmitted: refract (Snell) into the next layer or out
            uz[h[bounce]] = -uz[h[bounce]]
            cross = h[~bounce]
            ratio = (n_from / n_to)[~bounce]
            ux[cross] *= ratio
            uy[cross] *= ratio
            uz[cross] = np.sign(uz[cross]) * cos_t[~bounce]
            layer[cross] = next_layer[~bounce]
            out_top = cross[layer[cross] < 0]
            out_bottom = cross[layer[cross] >= n_layers]
            reflected += weight[out_top].sum()
            if radii.size and out_top.size:
                exit_radius = np.hypot(x[out_top], y[out_top])
                within += np.cumsum(np.bincount(np.searchsorted(radii, exit_radius), weights=weight[out_top], minlength=radii.size + 1))[:-1]
            transmitted += weight[out_bottom].sum()
            weight[out_top] = 0.0
            weight[out_bottom] = 0.0
            layer[out_top] = 0
            layer[out_bottom] = n_layers - 1
        # Russian roulette
        low = (weight > 0) & (weight < ROULETTE_WEIGHT)
        if low.any():
            survive = rng.random(int(low.sum())) < ROULETTE_SURVIVAL
            idx = np.flatnonzero(low)
            weight[idx] = np.where(survive, weight[idx] / ROULETTE_SURVIVAL, 0.0)
        alive = weight > 0
        if not alive.all():
            x, y, z, ux, uy, uz, weight, layer, optical = (a[alive] for a in (x, y, z, ux, uy, uz, weight, layer, optical))
            n = len(z)
    return reflected, transmitted, within
