"""Refinements of a functional map that alternate it with its point map: spectral ICP and ZoomOut.

Each step converts the current `C` to a point map (nearest neighbours in the spectral embedding,
`point_map`) and back (`functional_map_from_point_map`), so a refined map is always the functional
map of a point map. ICP (Ovsjanikov et al. 2012, section 6.1) keeps the size and projects to the
nearest orthogonal matrix, a near-isometry's functional map being orthogonal; ZoomOut (Melzi et al.
2019) grows the bases by `step` functions each step, from `C`'s size to `k_final`.

Each refinement is one compiled program: a `lax` loop whose steps call the nearest-neighbour search
(a host callback on a CPU) and the products. ZoomOut's growing bases are held at their final width
with the columns past the current size zeroed, which leaves the embedding distances unchanged, so one
program serves every step.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._compile import kernel
from .._errors import DDGInputError, check_count
from .._results import RESULTS, Solution, outcome
from ._point_map import check_functional_map, embedded_nearest, project_point_map
from ._shape import SpectralShape, require_spectral_shape


def icp_refine(
    C: Float[ArrayLike, "k_t k_s"],
    /,
    source: SpectralShape,
    target: SpectralShape,
    *,
    max_steps: int = 10,
    rtol: float = 1e-10,
    throw: bool = True,
) -> Float[Array, "k_t k_s"] | Solution:
    """Refine `C` by spectral ICP: point map, its functional map, the nearest orthogonal matrix; repeat.

    Each step: `p = point_map(C)`, `C' = Phi_t^T M_t Phi_s[p]` (`functional_map_from_point_map`),
    `C <- U I V^T` from the SVD `C' = U S V^T` (the nearest matrix with orthonormal rows or columns in
    the Frobenius norm). Stops after `max_steps` steps or once a step changes no entry of `C` by more
    than `rtol` times `C`'s largest entry (a fixed point: the point map stopped changing). Reaching
    `max_steps` is not a failure: ICP often ends cycling between a few nearby maps. Works under
    `jit`; not differentiable (it goes through point maps).

    Args:
        C: `(k_t, k_s)` initial functional map from the source to the target.
        source: the source `SpectralShape` (at least `k_s` eigenpairs).
        target: the target `SpectralShape` (at least `k_t` eigenpairs).
        max_steps: the most ICP steps (default 10, pyFM's `nit`).
        rtol: the change of `C`, relative to its largest entry, below which the steps stop (default 1e-10, pyFM's `tol`).
        throw: raise when the initial or the refined map is not finite (`RESULTS.nonfinite`: a NaN in a
            traced `C`, which cannot be refused first, or in the shapes' bases); with `False` return a `ddgjax.Solution` whose `stats` hold `num_steps` (the
            steps taken) and `change` (the last step's relative change: at most `rtol` at a fixed point).

    Returns:
        `(k_t, k_s)` refined functional map (in a `ddgjax.Solution` with `throw=False`).

    Reference: M. Ovsjanikov et al., "Functional maps: a flexible representation of maps between
    shapes" (SIGGRAPH 2012), section 6.1. pyFM: `refine.icp_refine(C, Phi_s[:, :k_s], Phi_t[:, :k_t],
    A2=M_t, nit=max_steps)` (a fixed point ends the steps early here with the same map).
    """
    source = require_spectral_shape("source", source)
    target = require_spectral_shape("target", target)
    k_t, k_s = check_functional_map("C", C, source, target)
    max_steps = check_count("max_steps", max_steps, minimum=0)
    if not (np.isscalar(rtol) and np.isreal(rtol) and 0 <= rtol < np.inf) or isinstance(rtol, bool):
        raise DDGInputError(f"rtol: expected a finite number >= 0, got {rtol!r}")
    C, result, stats = _icp(
        jnp.asarray(C), source.vectors[:, :k_s], target.vectors[:, :k_t], target.mass, rtol, max_steps=max_steps
    )
    return outcome(C, result, throw, stats)


@kernel(static_argnames=("max_steps",))
def _icp(C, source_vectors, target_vectors, target_mass, rtol, *, max_steps: int):
    k_t, k_s = C.shape

    def step(C):
        projected = project_point_map(
            embedded_nearest(C, source_vectors, target_vectors), source_vectors, target_vectors, target_mass
        )
        U, _, Vt = jnp.linalg.svd(projected, full_matrices=True)
        return U[:, : min(k_t, k_s)] @ Vt[: min(k_t, k_s)]

    def cond(carry):
        _, change, steps = carry
        return (steps < max_steps) & (change > rtol)

    def body(carry):
        C, _, steps = carry
        refined = step(C)
        change = jnp.max(jnp.abs(refined - C)) / jnp.maximum(jnp.max(jnp.abs(C)), jnp.finfo(C.dtype).tiny)
        return refined, change, steps + 1

    # A NaN in the initial map (traced, so not refused first) makes its point map arbitrary; the steps
    # after it are finite and mean nothing, so it is the input's finiteness that is reported too.
    finite = jnp.all(jnp.isfinite(C))
    C, change, num_steps = jax.lax.while_loop(cond, body, (C, jnp.asarray(jnp.inf, C.dtype), jnp.asarray(0)))
    result = RESULTS.where(finite & jnp.all(jnp.isfinite(C)), RESULTS.successful, RESULTS.nonfinite)
    return C, result, {"num_steps": num_steps, "change": change}


def zoomout_refine(
    C: Float[ArrayLike, "k_t k_s"],
    /,
    source: SpectralShape,
    target: SpectralShape,
    *,
    k_final: int,
    step: int = 1,
) -> Float[Array, "k_final k_final"]:
    """Refine `C` by ZoomOut: grow the bases `step` functions at a time up to `k_final`, through point maps.

    Each step: `p = point_map(C)` with `C` of size `(k_t, k_s)`, then `C <- Phi_t[:, :k_t + step]^T M_t
    Phi_s[p, :k_s + step]` (`functional_map_from_point_map`), each size capped at `k_final`; steps
    until both reach `k_final` (`ceil((k_final - min(k_t, k_s)) / step)` steps; none if `C` is
    already `(k_final, k_final)`). The upsampling of spectral information is what makes a coarse map
    accurate: a map of 30-50 functions refined to 100-150 (Melzi et al. 2019). Works under `jit`;
    not differentiable (it goes through point maps).

    Args:
        C: `(k_t, k_s)` initial functional map from the source to the target.
        source: the source `SpectralShape`, with at least `k_final` eigenpairs.
        target: the target `SpectralShape`, with at least `k_final` eigenpairs.
        k_final: the size of the refined map, at least `max(k_t, k_s)`.
        step: basis functions added per step (default 1, as pyFM and the paper).

    Returns:
        `(k_final, k_final)` refined functional map.

    Reference: S. Melzi, J. Ren, E. Rodolà, A. Sharma, P. Wonka, M. Ovsjanikov, "ZoomOut: spectral
    upsampling for efficient shape correspondence" (SIGGRAPH Asia 2019). pyFM:
    `refine.zoomout_refine(C, Phi_s, Phi_t, nit=(k_final - k) // step, step=step, A2=M_t)` for square `C`.
    """
    source = require_spectral_shape("source", source)
    target = require_spectral_shape("target", target)
    k_t, k_s = check_functional_map("C", C, source, target)
    k_final = check_count("k_final", k_final)
    if k_final < max(k_t, k_s) or k_final > min(source.k, target.k):
        raise DDGInputError(
            f"k_final: expected an integer in [{max(k_t, k_s)}, {min(source.k, target.k)}] (at least C's size, at most "
            f"the shapes' eigenpairs: make them with spectral_shape(mesh, k) for a larger k), got {k_final}"
        )
    step = check_count("step", step)
    steps = -(-(k_final - min(k_t, k_s)) // step)
    padded = jnp.zeros((k_final, k_final), jnp.result_type(C)).at[:k_t, :k_s].set(C)
    return _zoomout(
        padded, source.vectors[:, :k_final], target.vectors[:, :k_final], target.mass, k_t, k_s, step=step, steps=steps
    )


@kernel(static_argnames=("step", "steps"))
def _zoomout(C, source_vectors, target_vectors, target_mass, k_t, k_s, *, step: int, steps: int):
    columns = jnp.arange(C.shape[0])

    def body(i, C):
        # Sizes before this step; the columns past them are zeroed, which the distances do not see.
        size_t = jnp.minimum(k_t + i * step, C.shape[0])
        size_s = jnp.minimum(k_s + i * step, C.shape[1])
        matches = embedded_nearest(C, source_vectors * (columns < size_s), target_vectors * (columns < size_t))
        grown_s = source_vectors * (columns < size_s + step)
        grown_t = target_vectors * (columns < size_t + step)
        return project_point_map(matches, grown_s, grown_t, target_mass)

    return jax.lax.fori_loop(0, steps, body, C)
