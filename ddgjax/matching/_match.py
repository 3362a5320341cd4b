"""The whole matching pipeline with good defaults: bases, descriptors, functional map, refinement, point map."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .._compile import kernel
from .._errors import DDGInputError, check_choice, check_count
from .._results import RESULTS, Record, first_failure, raise_if_failed
from ..mesh import Mesh, require_mesh
from ._descriptors import descriptors
from ._functional_map import functional_map
from ._point_map import point_map
from ._refine import icp_refine, zoomout_refine
from ._shape import SpectralShape, require_connected, spectral_shape

#: The values of `refine=` of `match_shapes`.
REFINEMENTS = ("zoomout", "icp", None)


class MatchResult(Record):
    """What `match_shapes` returns (a pytree): the record of its run, with `value`, `result` and `stats` (`ddgjax.Record`).

    Attributes:
        point_map: `(n_target,)` for each target vertex, its source vertex.
        functional_map: `(k_t, k_s)` the final functional map (after refinement) from the source to the target.
        initial_functional_map: `(k, k)` the fitted map before refinement (step 3; its point map is
            `point_map(initial_functional_map, source, target)`).
        source: the source `SpectralShape` (its bases hold every eigenpair used).
        target: the target `SpectralShape`.
        result: the first failure of the pipeline's steps (`ddgjax.RESULTS.successful` when none failed).
        stats: each step's own `stats`: `{"source": ..., "target": ...}` of the two eigensolves and
            `{"functional_map": ...}` of the fit.
    """

    point_map: Int[Array, " n_target"]
    functional_map: Float[Array, "k_t k_s"]
    initial_functional_map: Float[Array, "k k"]
    source: SpectralShape
    target: SpectralShape
    result: RESULTS
    stats: dict

    @property
    def value(self) -> Int[Array, " n_target"]:
        """The answer: `point_map`."""
        return self.point_map


def match_shapes(
    source_mesh: Mesh,
    target_mesh: Mesh,
    *,
    k: int = 50,
    descriptor_kind: str = "wks",
    n_descriptors: int = 100,
    descriptor_weight: float = 1e-1,
    laplacian_weight: float = 1e-3,
    commutativity_weight: float = 1.0,
    orientation_weight: float = 1.0,
    orientation: str = "preserving",
    refine: str | None = "zoomout",
    k_final: int = 100,
    robust: bool = False,
    throw: bool = True,
) -> MatchResult:
    r"""Match two shapes: for each target vertex its source vertex, by functional maps refined with ZoomOut.

    $$\min_C \ \lVert C A - B \rVert^2 + \mu \lVert C \Lambda_s - \Lambda_t C \rVert^2 + \dots, \qquad \text{target vertex } y \mapsto \operatorname*{argmin}_x \lVert C \Phi_s(x) - \Phi_t(y) \rVert$$

    The pipeline (pyFM's `FunctionalMapping` preprocess / fit / zoomout_refine / get_p2p):

    1. `spectral_shape` of both meshes with `max(k, k_final)` eigenpairs (lumped Voronoi mass);
    2. `descriptors`: `n_descriptors` wave (default) or heat kernel signatures on each shape;
    3. `functional_map` of size `(k, k)` from the descriptors with the weights below (pyFM's `fit`
       defaults, plus the orientation-aware term of Ren et al. 2018 at `orientation_weight=1` (pyFM: 0),
       which tells a left-right symmetric shape's map from its mirror image);
    4. `refine`: `"zoomout"` (default) to `(k_final, k_final)` one function per step, `"icp"`
       (10 steps at size `k`), or `None`;
    5. `point_map` of the final map.

    The defaults (k = 50 for the fit, 100 WKS, ZoomOut to 100) are pyFM's usual pipeline; they match
    near-isometric pairs of a few thousand vertices to a mean geodesic error under 0.03 of
    $\sqrt{\text{area}}$ (tests/test_matching_pipeline.py).

    Supported: two connected surfaces (one connected component each, vertices joined by edges),
    near-isometric, either may have a boundary. A mesh of several components is refused
    (`DDGInputError`, before anything is computed): each component adds a zero eigenvalue, whose
    eigenvectors are any mix of the components' indicator functions, while step 3 fixes the map's
    first column as if `phi_0` were the constant function on both shapes. One component matched to
    two gives a fit with entries of 50 to 500 in the rows of the zero eigenvalues (a sphere against
    two spheres; at most 1 between isometric shapes); two against two maps each component to
    whichever one the eigensolver's basis pairs it with. Match the components one by one.

    Args:
        source_mesh: the source mesh (pyFM's mesh1).
        target_mesh: the target mesh (pyFM's mesh2).
        k: the functional map's size before refinement (pyFM's `fit(K=(k, k))`).
        descriptor_kind: `"wks"` (default) or `"hks"` (`descriptors(kind=)`).
        n_descriptors: descriptors per shape (`descriptors(n_descriptors=)`, default 100).
        descriptor_weight, laplacian_weight, commutativity_weight, orientation_weight: the
            energy's weights (`functional_map`).
        orientation: `"preserving"` (default) or `"reversing"` (a map to a mirror image).
        refine: `"zoomout"` (default), `"icp"` or `None`.
        k_final: ZoomOut's final size (default 100); ignored otherwise.
        robust: the intrinsic Delaunay Laplacian for both shapes (`spectral_shape(robust=True)`),
            for meshes with degenerate faces.
        throw: a failed eigensolve or functional-map solve raises (default); with `False` the
            pipeline runs to its end and the record's `result` is the first failure of its steps
            (`ddgjax.RESULTS.successful` when none failed).

    Returns:
        `MatchResult` with `.point_map` (its `value`), `.functional_map`, `.source`, `.target`, `.result`
        and `.stats`, with either `throw` (a record of the run, as the flows return).

    Reference: M. Ovsjanikov et al., "Functional maps" (SIGGRAPH 2012); S. Melzi et al., "ZoomOut"
    (SIGGRAPH Asia 2019). pyFM: `FunctionalMapping(mesh1, mesh2)`, `.preprocess(n_descr=100,
    descr_type="WKS")`, `.fit(K=(k, k), w_orient=...)`, `.zoomout_refine(nit=k_final - k)`, `.get_p2p(...)`.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(2)
        >>> x, y, z = sphere.vertices.T
        >>> bumpy = sphere.with_vertices(sphere.vertices * (1 + 0.3 * x**2 + 0.2 * y * z + 0.1 * z)[:, None])
        >>> turned = bumpy.with_vertices(bumpy.vertices[:, jnp.array([1, 0, 2])] * jnp.array([-1.0, 1.0, 1.0]))
        >>> match = ddgjax.matching.match_shapes(bumpy, turned, k=10, n_descriptors=20, k_final=30)
        >>> match.point_map.shape, bool(jnp.all(match.point_map == jnp.arange(162)))  # an isometry: every vertex found
        ((162,), True)
    """
    source_mesh = require_mesh("source_mesh", source_mesh)
    target_mesh = require_mesh("target_mesh", target_mesh)
    k = check_count("k", k, minimum=2)
    check_choice("refine", refine, REFINEMENTS)
    n_eigenpairs = k
    if refine == "zoomout":
        k_final = check_count("k_final", k_final)
        if k_final < k:
            raise DDGInputError(f"k_final: expected an integer >= k = {k} (ZoomOut grows the map), got {k_final}")
        n_eigenpairs = k_final
    for name, mesh in (("source_mesh", source_mesh), ("target_mesh", target_mesh)):
        if mesh.n_vertices <= n_eigenpairs:
            raise DDGInputError(
                f"{name}: {mesh.n_vertices} vertices are too few for {n_eigenpairs} eigenpairs: lower k and k_final"
            )
        require_connected(name, mesh, "match_shapes")
    source_solution = spectral_shape(source_mesh, n_eigenpairs, robust=robust, throw=False)
    target_solution = spectral_shape(target_mesh, n_eigenpairs, robust=robust, throw=False)
    source, target = source_solution.value, target_solution.value
    source_descriptors = descriptors(source, kind=descriptor_kind, n_descriptors=n_descriptors)
    target_descriptors = descriptors(target, kind=descriptor_kind, n_descriptors=n_descriptors)
    fit = functional_map(
        source,
        target,
        source_descriptors,
        target_descriptors,
        k_source=k,
        k_target=k,
        descriptor_weight=descriptor_weight,
        laplacian_weight=laplacian_weight,
        commutativity_weight=commutativity_weight,
        orientation_weight=orientation_weight,
        orientation=orientation,
        throw=False,
    )
    # A failed fit (reported below) may hold NaN: zeroed, the steps after it still run and the result says why.
    initial = C = _finite_or_zero(fit.value)
    refined_result, refine_stats = RESULTS.successful, {}
    if refine == "zoomout":
        C = zoomout_refine(C, source, target, k_final=k_final)
    elif refine == "icp":
        refined = icp_refine(C, source, target, throw=False)
        C, refined_result, refine_stats = refined.value, refined.result, refined.stats
    # Every step runs: a failure is reported once, at the end, with what the pipeline made of it.
    match = MatchResult(
        point_map=point_map(C, source, target),
        functional_map=C,
        initial_functional_map=initial,
        source=source,
        target=target,
        result=first_failure(source_solution.result, target_solution.result, fit.result, refined_result),
        stats={
            "source": source_solution.stats,
            "target": target_solution.stats,
            "functional_map": fit.stats,
            "refine": refine_stats,
        },
    )
    return raise_if_failed(match, match.result, throw)


@kernel
def _finite_or_zero(C: Float[Array, "k_t k_s"]) -> Float[Array, "k_t k_s"]:
    return jnp.where(jnp.isfinite(C), C, 0.0)
