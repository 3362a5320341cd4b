"""`nonnegative(t)`: a scalar declared `>= 0`, so that `t * A` keeps `A`'s semidefinite flags under jit.

`SparseMatrix` carries `positive_semidefinite` / `negative_semidefinite` as static flags (they become
lineax tags). `c * A` keeps them for a concrete `c >= 0`, but a traced `c` (a time step or a
regularisation weight passed into a jitted function) has no value to look at while tracing, so the
flags are dropped and `lineax.CG` refuses `M + t L`. Wrapping the scalar states the sign in the
program instead: `nonnegative(t) * L` keeps the flags, and the promise is checked where it can be,
on the host for a concrete `t` (`DDGInputError`) and at run time for a traced one
(`ddgjax.RESULTS.negative_value`, the library's results convention), so a negative `t` raises
rather than mis-tagging an indefinite operator.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Real

from .._errors import DDGInputError, is_traced
from .._results import RESULTS, raise_if_failed


class NonNegative(eqx.Module):
    """A real scalar known to be `>= 0` (made by `nonnegative`); multiplies a `SparseMatrix` keeping its flags.

    A concrete value is checked on construction; a traced one only by `nonnegative`, which puts the
    run-time check in front of it, so build it with `nonnegative(t)`.

    Attributes:
        value: `()` the scalar (behind a run-time check when it was traced).
    """

    value: Real[Array, ""]

    def __check_init__(self):
        if not is_traced(self.value) and not bool(self.value >= 0):
            raise DDGInputError(f"value: nonnegative() needs a value >= 0, got {np.asarray(self.value).item()!r}")


def nonnegative(value: Real[ArrayLike, ""] | NonNegative) -> NonNegative:
    """Declare a real scalar `>= 0`, so that `value * A` keeps `A`'s semidefinite flags inside jit.

    `nonnegative(t) * L` (or `L * nonnegative(t)`, `L / nonnegative(t)`, `A.shifted(nonnegative(s))`)
    has the values of `t * L` and keeps `positive_semidefinite` / `negative_semidefinite`, so
    `(M + nonnegative(t) * L).as_lineax_operator()` is tagged positive semidefinite and `lineax.CG`
    takes it with `t` traced. A concrete `value` is checked now (`DDGInputError` when negative or
    NaN); a traced one is checked when the program runs: a negative or NaN value raises with the
    message of `ddgjax.RESULTS.negative_value` (under `vmap`, when any member is) instead of tagging
    an indefinite operator PSD. Differentiable in `value`. SciPy has no flags, so no equivalent;
    lineax's tags are the same promise, unchecked.

    Args:
        value: a real scalar, `()` (a `NonNegative` is returned as it is).

    Returns:
        `NonNegative`.
    """
    if isinstance(value, NonNegative):
        return value
    value = jnp.asarray(value)
    if value.ndim != 0 or not (jnp.issubdtype(value.dtype, jnp.floating) or jnp.issubdtype(value.dtype, jnp.integer)):
        raise DDGInputError(f"value: expected a real scalar, got shape {value.shape} dtype {value.dtype}")
    if is_traced(value):
        result = RESULTS.where(value >= 0, RESULTS.successful, RESULTS.negative_value)
        value = raise_if_failed(value, result, throw=True)
    return NonNegative(value)  # a concrete value is checked on construction
