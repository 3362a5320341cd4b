"""The one finite-difference helper of the test suite: central differences along a direction, for gradient checks.

`jax.test_util.check_grads` checks JAX's own rules against finite differences on small inputs; the tests that
compare a derivative through a solve, an eigenproblem or a flow with the function's change along a random
direction use `central_difference` (error `O(eps^2)`, so `eps ~ 1e-6` leaves ~1e-10 relative in float64).
"""

from __future__ import annotations

import jax
import numpy as np


def central_difference(function, x, direction, eps: float = 1e-6):
    """`(f(x + eps d) - f(x - eps d)) / (2 eps)`: the derivative of `function` at `x` along `direction`.

    Several arguments: `x` and `direction` tuples of the same length, `function(*x)` moved along all of them at
    once (`central_difference(loss, (w, c), (dw, dc))` is the derivative `grad_w . dw + grad_c . dc`). A
    `function` that returns a tuple (or any pytree) of arrays gives the difference of each.
    """
    if isinstance(x, tuple):
        if not isinstance(direction, tuple) or len(direction) != len(x):
            raise ValueError("several arguments need a direction each (a tuple of the same length)")
        plus = function(*(point + eps * along for point, along in zip(x, direction)))
        minus = function(*(point - eps * along for point, along in zip(x, direction)))
    else:
        plus, minus = function(x + eps * direction), function(x - eps * direction)
    return jax.tree_util.tree_map(lambda high, low: (high - low) / (2 * eps), plus, minus)


def random_direction(shape, seed: int = 0) -> np.ndarray:
    """A standard normal direction of `shape` (reproducible by `seed`)."""
    return np.random.default_rng(seed).standard_normal(shape)
