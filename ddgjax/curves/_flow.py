"""`curve_shortening_flow`: the reading report's discrete curve-shortening flows, saved states and invariants.

The driver of the flows. One step (`p_i <- p_i + tau kappa_i N_i`, explicit or semi-implicit, with
its closed-form derivative) lives in `_flow_step`; the O(n)-per-step certificate that the curve
stayed simple in `_flow_certificate`; the loop in chunks, the progress bar and the first failure in
`ddgjax._loop`, shared with the other flows and `minimize_shape`.

References: the MA5210 reading report, "Curvature" (Figure 3); Dziuk 1994 (the semi-implicit
scheme); curvey's `CurveShorteningFlow`.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .._compile import kernel
from .._errors import DDGInputError, check_choice
from .._loop import (
    Failure,
    check_progress,
    check_steps,
    check_time_step,
    earliest,
    first_failure_step,
    no_failure,
    record,
    run_chunks,
    scan_steps,
)
from .._results import RESULTS, Record, is_failure, raise_if_failed
from ._curvature import KINDS, length, total_curvature
from ._curve import Curve, takes_curve, unchecked_curve
from ._flow_certificate import SIMPLICITY_CHECKS, state_outcome, track, tracker_start
from ._flow_step import METHODS, RESCALES, flow_step, rescaled, size
from ._invariants import centroid, cyclic_residual, enclosed_area, is_simple, isoperimetric_ratio


class CurveFlowResult(Record):
    """Saved states of a curve-shortening flow and the invariants the reading report discusses.

    `s = steps // save_every + 1` states are saved: the initial curve and every `save_every` steps.

    Attributes:
        points: `(s, n, 2)` positions; `value` is the last, `curve(i)` state `i` as a `Curve`.
        times: `(s,)` flow times `step * tau`.
        steps: `(s,)` step numbers.
        total_curvature: `(s,)` `sum theta` (the A-flow keeps `2 pi`).
        centroid: `(s, 2)` vertex centroid (the B-flow keeps it).
        length: `(s,)` total length (rescale="length" keeps it).
        area: `(s,)` signed enclosed area (rescale="area" keeps its absolute value).
        isoperimetric_ratio: `(s,)` `4 pi |A| / L^2` (tends to `pi / (n tan(pi / n))` for a
            regular polygon, 1 for a circle).
        cyclic_residual: `(s,)` relative spread of the vertices' distances to the fitted circle's
            centre (the D-flow drives it to 0).
        is_simple: `(s,)` no self-intersection (False also for non-finite points).
        result: the outcome of the first failing step (`ddgjax.RESULTS`): `successful`,
            `self_intersection` (the state was not simple) or `nonfinite` (NaN / inf positions:
            non-finite traced input, or an overflow). `curve_shortening_flow(..., throw=True)` (the
            default) raises instead of returning a failed result.
        first_failure_step: int scalar, the first step whose state was not simple or not finite
            (0: the initial curve), and `steps + 1` (one past the last step) when none was: so a
            saved state precedes every failure exactly when `steps < first_failure_step`, and
            `result` is successful exactly when `first_failure_step == steps[-1] + 1`. Exact with
            `check_simple="certified"` (the default) or `"every_step"`; the first failing saved
            step with `"saved"`.
        tau: the time step.
        kind, method, rescale, closed: the flow's settings (static).
    """

    points: Float[Array, "s n 2"]
    times: Float[Array, " s"]
    steps: Int[Array, " s"]
    total_curvature: Float[Array, " s"]
    centroid: Float[Array, "s 2"]
    length: Float[Array, " s"]
    area: Float[Array, " s"]
    isoperimetric_ratio: Float[Array, " s"]
    cyclic_residual: Float[Array, " s"]
    is_simple: Bool[Array, " s"]
    result: RESULTS
    first_failure_step: Int[Array, ""]
    tau: Float[Array, ""]
    kind: str = eqx.field(static=True)
    method: str = eqx.field(static=True)
    rescale: str | None = eqx.field(static=True)
    closed: bool = eqx.field(static=True)

    @property
    def value(self) -> Float[Array, "n 2"]:
        """The final positions, `points[-1]` (`(n, 2)`; `curve()` wraps them in a `Curve`)."""
        return self.points[-1]

    @property
    def stats(self) -> dict[str, Array]:
        """The run's history per saved state: `times`, `steps` and the invariants (`total_curvature`, `centroid`,
        `length`, `area`, `isoperimetric_ratio`, `cyclic_residual`, `is_simple`), as the fields hold them."""
        names = (
            "times",
            "steps",
            "total_curvature",
            "centroid",
            "length",
            "area",
            "isoperimetric_ratio",
            "cyclic_residual",
            "is_simple",
        )
        return {name: getattr(self, name) for name in names}

    @property
    def first_failure_time(self) -> Float[Array, ""]:
        """Flow time `first_failure_step * tau` of the first failing state, `inf` when the run succeeded."""
        return jnp.where(is_failure(self.result), self.first_failure_step * self.tau, jnp.inf)

    def curve(self, index: int = -1) -> Curve:
        """Saved state `index` (default: the final curve) as a `Curve` (not re-validated: it may be degenerate)."""
        return unchecked_curve(self.points[index], self.closed)


# XLA:CPU splits a flow step's costliest kernels across threads; below this size a kernel is too
# short for the thread handoff to pay (benchmarks/curves.py times both).
_SERIAL_BELOW = 100_000
_SERIAL_KERNELS = {"xla_disable_hlo_passes": "cpu-parallel-task-assigner"}


def _serial_kernels(points, *args, **kwargs) -> dict[str, str]:
    """Extra CPU compiler options for a flow on `points` (`kernel`): single-threaded kernels below `_SERIAL_BELOW` vertices.

    Chosen from the static shape at call time; under a caller's own `jit`, `grad` or `vmap` the
    caller's compilation settings apply instead (`ddgjax._compile`).
    """
    return _SERIAL_KERNELS if points.shape[-2] < _SERIAL_BELOW else {}


@kernel(static_argnames=("closed", "kind", "method", "rescale", "count", "check"), extra_cpu_options=_serial_kernels)
def _advance(points, tracker, start, tau, target, *, closed, kind, method, rescale, count, check):
    """Steps `start + 1, ..., start + count` from `points`, tracking simplicity as `check` says: `((points, tracker), points)`."""

    # Checkpointing each step makes reverse mode store only the positions per step (O(steps n)
    # memory) and recompute the step's few cheap internals, which costs less than writing and
    # rereading them all.
    @jax.checkpoint
    def step(carry, k):
        p, tracker = carry
        p = flow_step(p, tau, closed=closed, kind=kind, method=method)
        if rescale is not None:
            p = rescaled(p, closed, rescale, target)
        return (p, track(p, k, tracker, closed, check)), None

    (points, tracker), _ = scan_steps(step, (points, tracker), start, count)
    return (points, tracker), points


def _states(points, tau, *, closed, kind, method, rescale, steps, save_every, check, progress):
    """The saved states `(s, n, 2)` and the tracked `Failure`: `run_chunks` over chunks of `save_every` steps."""
    target = size(points, closed, rescale) if rescale is not None else jnp.zeros((), points.dtype)
    settings = {"closed": closed, "kind": kind, "method": method, "rescale": rescale, "count": save_every, "check": check}

    def chunk(carry, start):
        return _advance(*carry, start, tau, target, **settings)

    carry = (points, tracker_start(points, closed=closed, check=check))
    (_, (failure, _)), frames = run_chunks(
        chunk,
        carry,
        chunks=steps // save_every,
        every=save_every,
        progress=progress,
        description=f"curve-shortening flow {kind}",
    )
    return jnp.concatenate([points[None], frames]), failure


@kernel(
    static_argnames=("closed", "kind", "method", "rescale", "steps", "save_every", "check"), extra_cpu_options=_serial_kernels
)
def _run(points, tau, *, closed, kind, method, rescale, steps, save_every, check):
    """`_states` as one compiled program (the path without a progress bar)."""
    return _states(
        points,
        tau,
        closed=closed,
        kind=kind,
        method=method,
        rescale=rescale,
        steps=steps,
        save_every=save_every,
        check=check,
        progress=False,
    )


@takes_curve
def curve_shortening_flow(
    curve: Curve,
    *,
    kind: str,
    tau: float | Float[Array, ""],
    steps: int,
    save_every: int | None = None,
    method: str = "explicit",
    rescale: str | None = None,
    check_simple: str = "certified",
    progress: bool = False,
    throw: bool = True,
) -> CurveFlowResult:
    r"""Evolve a curve by the discrete curve-shortening flow of `kind`: `p_i <- p_i + tau kappa_i N_i`.

    $$p_i \leftarrow p_i + \tau \kappa_i N_i$$

    `kappa_i N_i` is `curvature_vectors(curve, kind=kind)` in the reading report's natural form
    (integrated for `"A"`, `"B"`, `"C"`; pointwise for `"D"`), a weighted second difference of the
    positions (`ddgjax.curves._flow_step`). The whole run is one compiled `lax.scan` (over saved
    chunks of `save_every` steps), differentiable end to end with respect to the initial points and
    `tau`, and `vmap`-able over a batch of curves:

        jax.vmap(lambda P: curve_shortening_flow(Curve(P), kind="B", tau=1e-3, steps=100, check_simple="saved").value)(Ps)

    (under `vmap`, `check_simple="saved"`: see below).

    What the report says each flow keeps (and the tests measure): A keeps the total curvature
    $2\pi$; B keeps the vertex centroid; D tends to a cyclic polygon; none keeps all three, and
    none is guaranteed to stay simple. Endpoints of an open curve stay fixed (they have no
    curvature).

    Outcomes (docs/conventions.md): a state that is not simple (self-intersecting or touching, the
    initial curve included) is `RESULTS.self_intersection`, NaN/inf positions `RESULTS.nonfinite`;
    `result` is the first failing step's and `first_failure_step` says which step that was. With
    `throw=True` (the default) such a run raises with the item's message:
    `equinox.EquinoxRuntimeError` when called eagerly or under `equinox.filter_jit`, a
    `jax.errors.JaxRuntimeError` carrying the same message under a plain `jax.jit`; under `vmap`
    it raises when any member failed. With `throw=False` it returns the record, to be inspected
    through `result`.

    Stability: explicit A, B, C need `tau` below about half the shortest edge; explicit D needs
    `tau` below about `(shortest edge)^2 / 4`; above it the curve tangles (self-intersects; the
    NaN-safe weights keep it finite). `method="semi-implicit"` solves $(I - \tau L(p))\, p^\mathrm{new} = p$ with
    the curvature weights frozen at the current curve (Dziuk 1994): stable for steps far beyond the
    explicit limit.

    Args:
        curve: initial curve (open or closed).
        kind: `"A"`, `"B"`, `"C"` or `"D"` (`curvature`).
        tau: time step, > 0 (may be traced: differentiate with respect to it, no recompilation).
        steps: number of steps, >= 1.
        save_every: save the state every this many steps; must divide `steps`. Default `steps`
            (save the initial and the final curve only).
        method: `"explicit"` (the report's iteration) or `"semi-implicit"`.
        rescale: `None`, `"length"` or `"area"`: after each step scale the curve about its vertex
            centroid back to the initial length / absolute area, so the limit shape can be watched.
            Closed curves only.
        check_simple: how the steps between saves are watched for self-intersection (the saved
            states are always tested; `ddgjax.curves._flow_certificate`).
            - `"certified"` (default): the exact first non-simple step at O(n) cost per step: a full
              O(n^2) test measures how far apart the edges that must not meet are, and each later
              step only bounds how far the curve has moved since; a new full test runs when the
              bound no longer certifies it. Under `jax.vmap` the lazy test becomes an every-step
              test (`lax.cond` turns into a select): use `"saved"` there.
            - `"saved"`: only the saved states; a self-intersection that appears and disappears
              between two saves goes unseen.
            - `"every_step"`: the full O(n^2) test after every step.
        progress: show a tqdm progress bar over the saved chunks (runs one compiled chunk per save
            from a host loop; needs concrete points and `tau`, i.e. not inside jit / vmap / grad).
        throw: raise when the run failed (default), or return the failed run to be inspected
            through `result` and `first_failure_step`.

    Returns:
        `CurveFlowResult` with the saved points `(s, n, 2)` (`value`: the final `(n, 2)`), times,
        invariants, `result` and `first_failure_step`.

    Raises:
        DDGInputError: `curve` not a `Curve`; bad `kind`, `method`, `rescale`, `check_simple`,
            `steps`, `save_every`; a concrete `tau` that is not finite and positive;
            `rescale` on an open curve; `progress=True` on traced points.
        equinox.EquinoxRuntimeError: with `throw=True`, a run that self-intersected or went
            non-finite (a `jax.errors.JaxRuntimeError` under a plain `jax.jit`; see above).

    Equivalent: curvey's `CurveShorteningFlow(resample_mode=None, curvature_fn=...)` (explicit,
    with curvey's finite-difference normals, host loop); no libigl / gpytoolbox counterpart.

    Examples:
        >>> import ddgjax
        >>> flower = ddgjax.curves.flower(64)
        >>> run = ddgjax.curves.curve_shortening_flow(flower, kind="B", tau=1e-3, steps=100, save_every=10)
        >>> run.points.shape, run.value.shape
        ((11, 64, 2), (64, 2))
        >>> bool(ddgjax.curves.length(ddgjax.Curve(run.value)) < ddgjax.curves.length(flower))
        True
    """
    check_choice("kind", kind, KINDS)
    check_choice("method", method, METHODS)
    check_choice("rescale", rescale, RESCALES)
    check_choice("check_simple", check_simple, SIMPLICITY_CHECKS)
    steps, save_every = check_steps(steps, save_every)
    if rescale is not None and not curve.closed:
        raise DDGInputError(f"rescale: expected None for an open curve (its endpoints are fixed), got {rescale!r}")
    points = curve.points
    tau = check_time_step(tau, points.dtype)
    progress = check_progress(progress, points, tau)
    settings = {"closed": curve.closed, "kind": kind, "method": method, "rescale": rescale}
    run = functools.partial(_states, progress=True) if progress else _run
    frames, failure = run(points, tau, **settings, steps=steps, save_every=save_every, check=check_simple)
    # save_every goes in as an array: a new value does not recompile.
    fields = _saved_invariants(frames, failure, tau, jnp.asarray(save_every, jnp.int32), closed=curve.closed)
    flow = CurveFlowResult(**fields, **settings)
    # Outside `_saved_invariants`' jit, so that an eager call raises equinox's own error type.
    return raise_if_failed(flow, flow.result, throw)


def _frame_invariants(frames, closed):
    def one(p):
        curve = unchecked_curve(p, closed)
        simple = is_simple(curve) & jnp.all(jnp.isfinite(p))
        invariants = (total_curvature(curve), centroid(curve), length(curve), enclosed_area(curve))
        return (*invariants, isoperimetric_ratio(curve), cyclic_residual(curve), simple, state_outcome(p, closed, simple))

    return jax.vmap(one)(frames)


@kernel(static_argnames=("closed",))
def _saved_invariants(frames, tracked: Failure, tau, save_every, *, closed) -> dict:
    """The array fields of `CurveFlowResult` (one compiled program per shape, whatever the kind / method / rescale)."""
    total, middle, size_, area, ratio, residual, simple, outcomes = _frame_invariants(frames, closed)
    steps = save_every * jnp.arange(frames.shape[0], dtype=jnp.int32)
    # The first failing saved state (`record` keeps the earliest).
    saved, _ = jax.lax.scan(lambda failure, frame: (record(failure, *frame), None), no_failure(), (steps, outcomes))
    failure = earliest(tracked, saved)
    return {
        "points": frames,
        "times": steps * tau,
        "steps": steps,
        "total_curvature": total,
        "centroid": middle,
        "length": size_,
        "area": area,
        "isoperimetric_ratio": ratio,
        "cyclic_residual": residual,
        "is_simple": simple,
        "result": failure.result,
        "first_failure_step": first_failure_step(failure, steps[-1]),
        "tau": tau,
    }
