"""The state of skinfit's lock-step solvers, one type for all three.

The spectral Gauss-Newton (``_spectra``), the two-root pixel solver (``_pixels``) and the bounded
transport polish (``_transport_polish``) each iterate a whole batch in step, with no per-problem
control flow: every iteration proposes a trial for every problem and keeps it where it is better.
What they carry per problem is the same three things:

- ``point``: where the solver stands (the best point so far), a pytree of arrays;
- ``cost``: the sum of squared residuals there (NaN: not evaluated yet);
- ``carry``: what this solver keeps besides, a pytree: the Gauss-Newton step proposed at the point
  (spectra), the 2x2 normal equations and the shading (pixels), the residual, Jacobian, secant
  curvature and damping (transport polish).

Fields are batched along leading axes when the solver runs on a batch; ``keep_where`` is the one
selection every solver makes between its current state and a trial.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, PyTree


class LockstepState(eqx.Module):
    point: PyTree[Array]
    cost: Array
    carry: Any = None

    def keep_where(self, keep: Array, other: "LockstepState") -> "LockstepState":
        """This state where ``keep`` (batch-shaped boolean), ``other`` elsewhere."""

        def select(a, b):
            mask = jnp.reshape(keep, jnp.shape(keep) + (1,) * (jnp.ndim(a) - jnp.ndim(keep)))
            return jnp.where(mask, a, b)

        return jax.tree_util.tree_map(select, self, other)


# The solvers' loops differentiate the model's evaluation in one loop step and use it in the next
# (see ``MeasurementModel.evaluation``); these two helpers are that evaluation and the loop's
# first, placeholder carry.
def evaluate_with_jacobian(evaluate, point):
    """(evaluate(point), its forward-mode Jacobian with respect to point) from one pass."""
    jacobian, value = jax.jacfwd(lambda x: (evaluate(x),) * 2, has_aux=True)(point)
    return value, jacobian


def placeholder(function, *args):
    """Zeros shaped like ``function(*args)``'s output, without evaluating it: the carry a loop
    holds before its first evaluation."""
    return jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), jax.eval_shape(function, *args))
