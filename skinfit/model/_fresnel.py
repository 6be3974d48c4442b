"""Fresnel reflectance of a smooth dielectric face (unpolarised light)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float


def fresnel_reflectance(cos_incidence: ArrayLike, n_from: ArrayLike, n_to: ArrayLike) -> Float[Array, "..."]:
    """Unpolarised Fresnel reflectance for light in index ``n_from`` meeting a face into ``n_to``
    at incidence cosine ``cos_incidence`` (in [0, 1]); 1 beyond the critical angle (NaN-free)."""
    c = jnp.clip(jnp.asarray(cos_incidence), 0.0, 1.0)
    n_from, n_to = jnp.asarray(n_from), jnp.asarray(n_to)
    sin_t2 = (n_from / n_to) ** 2 * (1.0 - c * c)
    total = sin_t2 >= 1.0
    cos_t = jnp.sqrt(jnp.where(total, 0.5, 1.0 - sin_t2))
    rs = ((n_from * c - n_to * cos_t) / (n_from * c + n_to * cos_t)) ** 2
    rp = ((n_from * cos_t - n_to * c) / (n_from * cos_t + n_to * c)) ** 2
    return jnp.where(total, 1.0, 0.5 * (rs + rp))


def normal_fresnel_reflectance(n_inside: ArrayLike, n_outside: ArrayLike = 1.0) -> Float[Array, "..."]:
    """Fresnel reflectance at normal incidence, ((n1 - n2) / (n1 + n2))^2."""
    n_inside, n_outside = jnp.asarray(n_inside), jnp.asarray(n_outside)
    return jnp.square((n_inside - n_outside) / (n_inside + n_outside))
