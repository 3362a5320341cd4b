"""`cyclic_shift`: `jnp.roll` as a linear JAX primitive whose transpose is the opposite roll.

JAX builds `jnp.roll` from two slices and a concatenation, so reverse mode transposes it into two
zero-padded copies and an addition, which XLA's CPU backend emits as separate kernels. Inside the
curve flows' tangent (`ddgjax.curves._flow_step._explicit_step_jvp`, transposed once per step of a
thousand-step gradient) that made the backward pass several times the forward one. A roll is a
permutation, so its transpose is the roll the other way: this primitive says so.

- forward (`jit`, eager): lowered to `jnp.roll`;
- forward mode (`jax.jvp`): linear, so the tangent is `cyclic_shift` of the tangent;
- reverse mode (`jax.grad`, `jax.linear_transpose`): `cyclic_shift(ct, -shift, axis)`;
- `vmap`: the same roll on the batched array, `axis` moved past the batch axis.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.extend.core import Primitive
from jax.interpreters import ad, batching, mlir
from jaxtyping import Array, Float

from ._errors import DDGInputError

cyclic_shift_p = Primitive("ddgjax_cyclic_shift")


def cyclic_shift(x: Float[Array, "..."], shift: int, axis: int = 0) -> Float[Array, "..."]:
    """`jnp.roll(x, shift, axis)`: `y[i] = x[(i - shift) mod n]` along `axis`, with a roll as transpose.

    Same values as `jnp.roll`; only its derivatives are compiled differently (module docstring).
    Reference: JAX documentation, "JAX internals: primitives" (linear primitives and transposition).

    Args:
        x: array with at least one axis.
        shift: number of places, a Python int (positive: towards higher indices).
        axis: the axis to roll along (negative counts from the end).

    Returns:
        Array of `x`'s shape and dtype.

    Raises:
        DDGInputError: `x` is a scalar, or `axis` is not one of its axes.
    """
    x = jnp.asarray(x)
    if x.ndim == 0 or not -x.ndim <= int(axis) < x.ndim:
        raise DDGInputError(f"axis: expected an axis of an array of shape {x.shape}, got {axis}")
    return cyclic_shift_p.bind(x, shift=int(shift), axis=int(axis) % x.ndim)


def _impl(x, *, shift, axis):
    return jnp.roll(x, shift, axis=axis)


def _transpose(cotangent, x, *, shift, axis):
    if type(cotangent) is ad.Zero:
        return [ad.Zero(x.aval)]
    return [cyclic_shift_p.bind(cotangent, shift=-shift, axis=axis)]


def _batch(args, dims, *, shift, axis):
    (x,), (dim,) = args, dims
    # The unbatched axis `axis` sits at `axis + 1` in the batched array when the batch axis comes before it.
    return cyclic_shift_p.bind(x, shift=shift, axis=axis + (dim <= axis)), dim


cyclic_shift_p.def_impl(_impl)
cyclic_shift_p.def_abstract_eval(lambda x, *, shift, axis: jax.core.ShapedArray(x.shape, x.dtype, weak_type=x.weak_type))
mlir.register_lowering(cyclic_shift_p, mlir.lower_fun(_impl, multiple_results=False))
ad.deflinear2(cyclic_shift_p, _transpose)
batching.primitive_batchers[cyclic_shift_p] = _batch
