"""The loop every ddgjax flow and optimisation driver runs: steps in chunks, saved states, the first failure.

A driver (`curve_shortening_flow`, `mean_curvature_flow`, `minimize_shape`) takes `steps` steps and
keeps something every `every` steps (a saved state, a loss history). It is written as

- a `step(carry, k) -> (carry, output)` for step number `k` (steps are numbered `1, ..., steps`;
  state `k` is the state after `k` steps, state 0 the input), run `every` at a time by
  `scan_steps` inside a compiled chunk `chunk(carry, start) -> (carry, saved)`;
- `run_chunks(chunk, carry, ...)`, which runs the chunks: as one outer `lax.scan` (traced inside the
  driver's own `kernel`, so that the whole run is one compiled program that `jit`, `grad` and `vmap`
  see through), or, with `progress=True`, from a host loop that calls the compiled chunk once per
  chunk and advances a tqdm bar. Both paths run the same chunk, so they give the same numbers;
- a `Failure` in the carry: the first step whose outcome (an item of `ddgjax.RESULTS`) was not a
  success, and that outcome (`record`); the driver's record reports it as `.result` and
  `first_failure_step`, `steps + 1` when no step failed (docs/conventions.md, Outcomes).

Why a host loop for the bar: diffrax's `TqdmProgressMeter` updates its bar from inside the compiled
loop through a host callback; chunks called from the host keep the compiled program free of
callbacks (which JAX's persistent cache does not keep, and which `vmap` would multiply).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Int, PyTree, Real

from ._errors import DDGInputError, check_count, is_traced
from ._results import RESULTS, is_failure

# The first failing step before any failure: above every step number, so that "a failure lies
# before step k" is `failure.step < k` and `record` keeps the minimum.
_NOT_YET = np.iinfo(np.int32).max


class Failure(NamedTuple):
    """The first failing step of a loop so far and its outcome: part of a driver's scan carry.

    Attributes:
        step: int32 scalar, the number of the first step whose outcome failed (0: the input state),
            a large sentinel while none has.
        result: that step's outcome, an item of `RESULTS` (`RESULTS.successful` while none failed).
    """

    step: Int[Array, ""]
    result: RESULTS


def no_failure() -> Failure:
    """The `Failure` of a loop in which nothing has failed yet."""
    return Failure(jnp.full((), _NOT_YET, jnp.int32), RESULTS.successful)


def record(failure: Failure, step: Int[ArrayLike, ""], result: RESULTS) -> Failure:
    """`failure`, or step `step` with its outcome `result` when that failed before any recorded failure."""
    new = is_failure(result) & (step < failure.step)
    return Failure(jnp.where(new, step, failure.step).astype(jnp.int32), RESULTS.where(new, result, failure.result))


def earliest(first: Failure, second: Failure) -> Failure:
    """The earlier of two failures (`first` on a tie)."""
    return record(first, second.step, second.result)


def failed_before(failure: Failure, step: Int[ArrayLike, ""]) -> Bool[Array, ""]:
    """Whether a step before `step` failed."""
    return failure.step < step


def first_failure_step(failure: Failure, steps: int | Int[ArrayLike, ""]) -> Int[Array, ""]:
    """The number of the first failing step, `steps + 1` (one past the last step) when none failed."""
    return jnp.minimum(failure.step, jnp.asarray(steps, jnp.int32) + 1)


def finite_outcome(values: PyTree) -> RESULTS:
    """`RESULTS.successful` when every entry of `values` is finite, else `RESULTS.nonfinite`."""
    finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(leaf)) for leaf in jax.tree.leaves(values)]))
    return RESULTS.where(finite, RESULTS.successful, RESULTS.nonfinite)


def check_steps(steps: int, save_every: int | None) -> tuple[int, int]:
    """`(steps, save_every)` as ints, `save_every` defaulting to `steps` (save the input and the final state).

    Raises `DDGInputError` unless `steps >= 1`, `save_every >= 1` and `save_every` divides `steps`.
    """
    steps = check_count("steps", steps)
    save_every = steps if save_every is None else check_count("save_every", save_every)
    if steps % save_every:
        raise DDGInputError(f"save_every: expected a divisor of steps = {steps}, got {save_every}")
    return steps, save_every


def check_time_step(tau: Real[ArrayLike, ""], dtype) -> Real[Array, ""]:
    """The time step `tau` as a scalar array of `dtype`: a finite real number `> 0` (checked when concrete).

    A traced `tau` (inside `jit` / `grad` / `vmap`) cannot be checked and passes, so that a flow stays
    differentiable in it.
    """
    if np.ndim(tau) != 0 or np.iscomplexobj(tau) or isinstance(tau, (bool, np.bool_)):
        raise DDGInputError(f"tau: expected a real scalar time step > 0, got {tau!r}")
    if not is_traced(tau) and not (math.isfinite(float(tau)) and float(tau) > 0):
        raise DDGInputError(f"tau: expected a finite time step > 0, got {np.asarray(tau).item()!r}")
    # Concrete: moved to the device without an eager program (`jnp.asarray(...).astype` compiles one).
    return jnp.asarray(tau).astype(dtype) if is_traced(tau) else jax.device_put(np.asarray(tau, dtype))


def check_progress(progress: bool, *values: PyTree) -> bool:
    """`progress`, after checking that a progress bar can be driven: `DDGInputError` when `values` hold tracers."""
    if not isinstance(progress, (bool, np.bool_)):
        raise DDGInputError(f"progress: expected True or False, got {progress!r}")
    if progress and any(is_traced(leaf) for leaf in jax.tree.leaves(values)):
        raise DDGInputError(
            "progress: expected concrete inputs (a host loop drives the bar); use progress=False under jit / vmap / grad"
        )
    return bool(progress)


def scan_steps(
    step: Callable[[PyTree, Int[Array, ""]], tuple[PyTree, PyTree]],
    carry: PyTree,
    start: Int[ArrayLike, ""],
    count: int,
    *,
    last: Int[ArrayLike, ""] | None = None,
    idle: PyTree = None,
) -> tuple[PyTree, PyTree]:
    """Steps `start + 1, ..., start + count` of `step(carry, k) -> (carry, output)` in one `lax.scan`.

    Returns the final carry and the outputs stacked on a leading axis of length `count`. With
    `last`, a step `k > last` is skipped: the carry passes through and its output is `idle` (a
    pytree shaped like `step`'s output), so that one compiled chunk also serves a last chunk that
    reaches past the end of the run.
    """
    numbers = jnp.asarray(start, jnp.int32) + 1 + jnp.arange(count, dtype=jnp.int32)
    body = step
    if last is not None:

        def body(carry, k):
            return jax.lax.cond(k <= last, step, lambda carry, _: (carry, idle), carry, k)

    return jax.lax.scan(body, carry, numbers)


def run_chunks(
    chunk: Callable[[PyTree, Int[Array, ""]], tuple[PyTree, PyTree]],
    carry: PyTree,
    *,
    chunks: int,
    every: int,
    steps: int | None = None,
    progress: bool = False,
    description: str = "",
    postfix: Callable[[PyTree], dict[str, Any]] | None = None,
) -> tuple[PyTree, PyTree]:
    """`chunks` calls `chunk(carry, start) -> (carry, saved)` with `start = 0, every, 2 every, ...`.

    Returns the final carry and what each chunk saved, stacked on a leading axis of length `chunks`.

    - `progress=False`: one `lax.scan` over the chunks. Trace it inside the driver's compiled kernel,
      so that the whole run is one program (and `jit` / `grad` / `vmap` see through it).
    - `progress=True`: a host loop with a tqdm bar of `steps` steps (default `chunks * every`)
      labelled `description`, advanced by `every` after each chunk (the last one by what is left);
      `chunk` must then be compiled (a `kernel` called outside any transformation), and `postfix`,
      if given, maps a chunk's `saved` to the bar's postfix (e.g. the current loss).
    """
    starts = every * jnp.arange(chunks, dtype=jnp.int32)
    if not progress:
        return jax.lax.scan(chunk, carry, starts)
    from tqdm.auto import tqdm

    steps = chunks * every if steps is None else steps
    saved = []
    with tqdm(total=steps, desc=description, unit="step") as bar:
        for start in starts:
            carry, chunk_saved = chunk(carry, start)
            jax.block_until_ready(chunk_saved)
            saved.append(chunk_saved)
            bar.update(min(every, steps - int(start)))
            if postfix is not None:
                bar.set_postfix(postfix(chunk_saved))
    return carry, jax.tree.map(lambda *leaves: jnp.stack(leaves), *saved)
