"""Small dense linear algebra that vectorises well under vmap on CPU."""

from __future__ import annotations

import jax.numpy as jnp


def solve_normal(a, b):
    """Solve the small SPD system a x = b by an unrolled Cholesky factorisation.

    Batched LAPACK calls on tiny matrices cost more than the model evaluation on CPU; this is a few
    dozen fused multiply-adds. The diagonal is floored relative to its largest entry so that a
    direction the data do not constrain (a zero Jacobian column) gets a zero step, not a NaN.
    """
    n = a.shape[-1]
    floor = 1e-12 * jnp.max(jnp.diagonal(a)) + 1e-300
    lower = [[None] * n for _ in range(n)]
    for j in range(n):
        diag = a[j, j] + floor - sum(lower[j][k] ** 2 for k in range(j))
        lower[j][j] = jnp.sqrt(jnp.maximum(diag, floor))
        for i in range(j + 1, n):
            lower[i][j] = (a[i, j] - sum(lower[i][k] * lower[j][k] for k in range(j))) / lower[j][j]
    y = [None] * n
    for i in range(n):
        y[i] = (b[i] - sum(lower[i][k] * y[k] for k in range(i))) / lower[i][i]
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - sum(lower[k][i] * x[k] for k in range(i + 1, n))) / lower[i][i]
    return jnp.stack(x)
