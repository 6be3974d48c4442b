"""Warm-start table for fits: model spectra over the parameter box, searched in a reduced basis.

The table holds, for a grid of the free chromophores (log-spaced C_m and C_h, interior beta_m), each
entry's weighted model spectrum, its weighted Jacobian and Gauss-Newton step operator
(J^T W J)^-1 J^T W. A target takes its nearest entry in each *start group* (bands of beta_m and
C_h: the fit has distinct local minima in different bands, for example C_h = 0 against C_h = 0.1
for pheomelanin-rich dark skin, 0.02 % apart in reflectance), applies that entry's precomputed
Gauss-Newton correction, and the groups are ranked by the cost the linearised model predicts after
the correction; no model evaluation is needed.

Nearest entries are searched on the leading principal components of the weighted table spectra
(distances in 31 wavelengths cost about four times more and find the same entries), and groups are
stored contiguously so that one argmin per row serves all groups.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._caching import BoundedCache
from ..model import cache_key
from ._variables import (
    CHROMOPHORES,
    MODEL,
    STARTS,
    VARIABLES,
    MeasurementModel,
    model_constant,
    to_unbounded,
)

#: Grid of each free chromophore (index by the table shape (C_m, beta_m, C_h)).
_AXES = {
    "melanin": lambda size: np.geomspace(5e-4, 0.8, size),
    "melanin_blend": lambda size: np.linspace(0.05, 0.95, size),  # interior: starts off the bounds
    "haemoglobin": lambda size: np.geomspace(5e-4, 0.5, size),
}

#: Targets per block of the nearest-entry search.
_SEARCH_BATCH = 128

#: Relative part of the table's spread left out of the search basis, and the basis's (padded) size.
_BASIS_TOLERANCE = 1e-4
_BASIS_ROWS = 24


class FitTable(eqx.Module):
    """Table entries of G groups of N entries each, for m wavelengths and f free variables."""

    grid_u: Float[Array, "G N f"]  # unbounded coordinates of the entries
    spectra: Float[Array, "G N m"]  # model spectra (unweighted)
    weighted_jacobian: Float[Array, "G N m f"]  # w * d spectrum / du
    step_operator: Float[Array, "G N f m"]  # (J^T W J)^-1 J^T W
    weights: Float[Array, " m"]
    basis: Float[Array, "K m"]  # principal directions of the weighted spectra
    mean: Float[Array, " m"]
    coords: Float[Array, "G N K"]  # entries in the basis (float32)
    coords_sq: Float[Array, "G N"]  # (float32)

    def _nearest(self, z):
        """Index of the nearest entry in each group, (n, G), for targets z (n, K) in the basis."""
        n_groups, n_entries, rank = self.coords.shape
        distance = self.coords_sq.reshape(-1) - 2.0 * z @ self.coords.reshape(-1, rank).T
        distance = distance.reshape(-1, n_groups, n_entries)
        # min, then the index where it occurs: on CPU two plain reductions are twice as fast as argmin
        at_min = distance == jnp.min(distance, axis=-1, keepdims=True)
        return jnp.max(jnp.where(at_min, jnp.arange(n_entries, dtype=distance.dtype), -1.0), axis=-1).astype(jnp.int32)

    def candidates(self, target: Float[Array, "n m"], count: int) -> Float[Array, "n count f"]:
        """Corrected starts from the ``count`` groups with the lowest predicted cost, best first."""
        w = self.weights
        # float32 suffices to find the nearest entries, and halves the cost of this, the largest
        # product of the fit (every target against every entry)
        z = ((w * target - self.mean) @ self.basis.T).astype(self.coords.dtype)  # (n, K)
        n = z.shape[0]
        if n > _SEARCH_BATCH and n % _SEARCH_BATCH == 0:  # keep the distance block in cache
            nearest = jax.lax.map(self._nearest, z.reshape(-1, _SEARCH_BATCH, z.shape[1])).reshape(n, -1)
        else:
            nearest = self._nearest(z)  # (n, G)
        groups = jnp.arange(self.grid_u.shape[0])[None, :]
        u0 = self.grid_u[groups, nearest]
        spectra = self.spectra[groups, nearest]
        difference = target[:, None, :] - spectra  # (n, G, m)
        # u spans pi: clip so that a poor linearisation cannot throw the start across the range
        step = jnp.clip(jnp.einsum("ngfm,ngm->ngf", self.step_operator[groups, nearest], difference), -0.5, 0.5)
        predicted = w * difference - jnp.einsum("ngmf,ngf->ngm", self.weighted_jacobian[groups, nearest], step)
        cost = jnp.sum(predicted**2, axis=-1)
        order = jnp.argsort(cost, axis=1)[:, :count]
        return jnp.take_along_axis(u0 + step, order[:, :, None], axis=1)


def build_fit_table(
    model: MeasurementModel, wavelengths: tuple, weights: tuple, shape: tuple, groups: tuple
) -> FitTable:
    """The table for a measurement model on a wavelength grid with per-wavelength weights.

    Args:
        shape: grid sizes of (C_m, beta_m, C_h); axes of chromophores that are not free are dropped.
        groups: start-group bands along (beta_m, C_h).

    Variables other than the chromophores sit at their fixed value or documented start. Tables are
    kept for the last few models (keyed by their values): a fit with the same model reuses one, and a
    model with other constants builds its own without recompiling.
    """
    key = (cache_key(model), wavelengths, weights, tuple(shape), tuple(groups))
    return _TABLES.get(key, lambda: _build_fit_table(model, wavelengths, weights, tuple(shape), tuple(groups)))


_TABLES = BoundedCache(8)


def _start_value(model: MeasurementModel, name: str) -> float:
    var = VARIABLES[name]
    if name in STARTS:
        return STARTS[name]
    if var.default == MODEL:
        return model_constant(model.skin, name)
    return float(var.default)


def _build_fit_table(model, wavelengths, weights, shape, groups) -> FitTable:
    free_axes = [
        _AXES[name](shape[CHROMOPHORES.index(name)]) if name in CHROMOPHORES else np.array([_start_value(model, name)])
        for name in model.free
    ]
    mesh = np.meshgrid(*free_axes, indexing="ij")
    grid_u = np.stack([to_unbounded(n, m.ravel()) for n, m in zip(model.free, mesh)], axis=-1)
    w = np.asarray(weights)

    # batched so that memory stays bounded (the finite-port model carries a q axis); padded to
    # whole batches, since a remainder batch would be compiled separately
    batch = min(256, len(grid_u))
    padded = np.concatenate([grid_u, np.repeat(grid_u[-1:], -len(grid_u) % batch, axis=0)])
    spectra, jw, step_op = (np.asarray(a)[: len(grid_u)] for a in _table_entries(model, jnp.asarray(padded), wavelengths, jnp.asarray(w), batch))

    members = _group_members(model.free, free_axes, groups)
    size = max(len(m) for m in members)
    # equal-size groups: pad each with repeats of its last entry (a repeat never changes an argmin)
    order = np.stack([np.concatenate([m, np.repeat(m[-1:], size - len(m))]) for m in members])

    weighted = w * spectra
    mean = weighted.mean(axis=0)
    _, singular, vt = np.linalg.svd(weighted - mean, full_matrices=False)
    tail = np.sqrt(np.cumsum((singular**2)[::-1])[::-1] / np.sum(singular**2))  # tail[k]: left out by keeping k
    rank = int(np.argmax(np.append(tail, 0.0) <= _BASIS_TOLERANCE))
    # a fixed number of rows (zero rows beyond the rank change no distance): the search compiles
    # once per grid, whatever the model's values
    size = min(_BASIS_ROWS, vt.shape[0])
    basis = np.zeros((size, vt.shape[1]))
    basis[: min(max(rank, 1), size)] = vt[: min(max(rank, 1), size)]
    coords = (weighted - mean) @ basis.T
    grouped = lambda a, dtype=float: jnp.asarray(a[order].astype(dtype))  # noqa: E731 - NumPy first: no compilations
    return FitTable(
        grid_u=grouped(grid_u),
        spectra=grouped(spectra),
        weighted_jacobian=grouped(jw),
        step_operator=grouped(step_op),
        weights=jnp.asarray(w),
        basis=jnp.asarray(basis),
        mean=jnp.asarray(mean),
        coords=grouped(coords, np.float32),
        coords_sq=grouped(np.sum(coords**2, axis=1), np.float32),
    )


@eqx.filter_jit
def _table_entries(model, grid_u, wavelengths, w, batch):
    """Spectrum, weighted Jacobian and Gauss-Newton step operator of every entry (compiled once per
    measurement structure and grid: the model's values are traced)."""
    lam = np.asarray(wavelengths)

    def entry(u):
        spectrum_and_jacobian = jax.jacfwd(lambda x: (model.spectrum(x, lam),) * 2, has_aux=True)
        jacobian, spectrum = spectrum_and_jacobian(u)
        jw = w[:, None] * jacobian  # (m, f)
        normal = jw.T @ jw + 1e-10 * jnp.eye(u.shape[-1])
        return spectrum, jw, jnp.linalg.solve(normal, jw.T * w[None, :])

    return jax.lax.map(entry, grid_u, batch_size=batch)


def _group_members(free, free_axes, groups) -> list[np.ndarray]:
    """Entry indices of each start group: bands of the blend and haemoglobin axes (one group if neither is free)."""
    index = np.meshgrid(*(np.arange(len(a)) for a in free_axes), indexing="ij")
    label = np.zeros(index[0].size, dtype=int)
    for name, count in zip(("melanin_blend", "haemoglobin"), groups):
        if name in free:
            axis = free.index(name)
            label = label * count + index[axis].ravel() * count // len(free_axes[axis])
    return [np.flatnonzero(label == g) for g in np.unique(label)]
