"""Hodge decomposition of a discrete 1-form into exact, co-exact and harmonic parts, differentiably.

On a triangle mesh every 1-form `omega` (one number per edge, `ddgjax.dec` conventions) splits as

    omega = d alpha + delta beta + gamma,

`d alpha = d0 alpha` exact (a 0-form `alpha` on the vertices), `delta beta = *1^{-1} d1^T *2 beta`
co-exact (a 2-form `beta` on the faces), and `gamma` harmonic: closed (`d1 gamma = 0`) and co-closed
(`d0^T *1 gamma = 0`). The three parts are orthogonal in the `*1` pairing `<a, b> = a^T *1 b` (an
inner product where `*1 > 0`; `d1 d0 = 0` makes `d alpha` and `delta beta` orthogonal whatever `*1`
is), and the harmonic forms
are the first cohomology: `2 g` of them on a closed surface of genus `g`, `2 g + b - 1` on one with
`b` boundary loops (per connected component).

**How it is computed.** Crane's DDG notes (and the DDG exercises' `HodgeDecomposition`) solve

    d0^T *1 d0 alpha = d0^T *1 omega,        d1 *1^{-1} d1^T beta~ = d1 omega,

and take `gamma = omega - d alpha - *1^{-1} d1^T beta~`. The first matrix is the cotan Laplacian `L`,
positive semidefinite on every mesh (a Gram matrix of hat-function gradients). The second is not: the
circumcentric `*1 = (cot a + cot b) / 2` is negative on every non-Delaunay edge (1076 of the 9216
edges of the DDG exercises' genus-2 mesh), so `d1 *1^{-1} d1^T` is indefinite and neither a Cholesky
factorisation nor conjugate gradients can solve it. ddgjax therefore gets the co-exact part from the
other two, with only positive semidefinite solves:

1. `d alpha`: `L alpha = d0^T *1 omega` (one vertex pinned per connected component, which fixes the
   constant and leaves `d alpha` unchanged; `linear_solve` on the free-free block).
2. A basis of the harmonic forms: the closed, non-exact 1-forms `eta_1 .. eta_k` of a tree-cotree
   decomposition (Eppstein 2003; the DDG exercises' `TreeCotree` and `HarmonicBases`), built once per
   connectivity on the host, made co-closed by the same solve, `h_i = eta_i - d0 a_i` with
   `L a_i = d0^T *1 eta_i` (one block solve together with step 1).
3. `gamma`: the `*1`-orthogonal projection of `omega - d alpha` onto `span(h)`, i.e.
   `gamma = H G^{-1} H^T *1 (omega - d alpha)` with the `k x k` Gram matrix `G = H^T *1 H`.
4. `delta beta = omega - d alpha - gamma`.

It is the same decomposition: the remainder in step 4 is `*1`-orthogonal to the exact forms (step 1)
and to the harmonic ones (step 3), hence to every closed form, which is what being co-exact means
(for a non-degenerate `*1`). The tests check it against the DDG exercises' solution and against
SciPy's LU on the face system (the co-exact parts agree to ~1e-13). With `dual="barycentric"`, `*1` is positive everywhere and
`<a, b> = a^T *1 b` a true inner product. The cotan `*1` is exactly 0 on an edge whose opposite angles
sum to pi (the diagonal of a cyclic quadrilateral, e.g. every diagonal of `ddgjax.mesh.torus` and of
a rectangular grid); there `*1^{-1}`, hence the co-exact part, is undefined and the split returned is
one of many (the three parts still sum to `omega`, closed and co-closed as stated). Use
`dual="barycentric"` on such meshes.

Differentiable in `omega` and in the vertex positions (through `*1`, `L` and the solves) in forward
and reverse mode, under `jit` and `vmap` over `omega`. The mesh must be consistently oriented (`d1`
and the co-exact part need an orientation). Two steps can fail on the values: the Laplacian solve of
steps 1-2 (`ddgjax.solve.linear_solve`, backend `solver=`) and the Gram system of step 3 (singular
when `*1` vanishes on the harmonic forms); the outcome is the first failing one (`ddgjax.RESULTS`,
`throw=`). An eager call runs one compiled program; the tree-cotree basis and the storage plans are
host work before it, once per connectivity.

References: K. Crane, *Discrete Differential Geometry: An Applied Introduction* (2020), "Hodge
decomposition"; K. Crane, F. de Goes, M. Desbrun, P. Schroeder, *Digital Geometry Processing with
Discrete Exterior Calculus* (SIGGRAPH course 2013), section 7; D. Eppstein, "Dynamic generators of
topologically embedded graphs" (SODA 2003), tree-cotree. Equivalents: the DDG exercises'
`HodgeDecomposition` (`projects/vector-field-decomposition`); geometry-central provides the DEC
operators (`requireDECOperators`) but no decomposition routine; libigl and gpytoolbox have none.
"""

from __future__ import annotations

import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jaxtyping import Array, ArrayLike, Float
from scipy.sparse import csgraph

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_choice, check_float_shape
from .._options import DUAL_CELLS, check_solver
from .._results import RESULTS, Solution, first_failure, outcome
from ..dec import d0, hodge_star_entries
from ..discretization.internal import DirichletData
from ..laplacian import TriangulationPlan, cotan_laplacian_from_lengths_sq
from ..laplacian.internal import dec_plan, vertex_plan
from ..mesh import Mesh, MeshTopology, face_edge_lengths_sq, require_mesh
from ..solve import linear_solve
from ..sparse import CongruencePlan, DirichletPlan, congruence, dirichlet_blocks


class HodgeDecomposition(eqx.Module):
    """The three parts of `hodge_decomposition(mesh, omega)`, each the shape of `omega`, summing to it.

    A module rather than a bare tuple so each part has its name (`exact` vs `coexact` is easy to swap
    by position), while `exact, coexact, harmonic = hodge_decomposition(mesh, omega)` still unpacks
    in the order of the formula `omega = d alpha + delta beta + gamma`.

    Attributes:
        exact: `d alpha`, `(ne,)` or `(ne, k)`.
        coexact: `delta beta`, the same shape.
        harmonic: `gamma`, the same shape.
    """

    exact: Float[Array, "ne *k"]
    coexact: Float[Array, "ne *k"]
    harmonic: Float[Array, "ne *k"]

    def __iter__(self):
        return iter((self.exact, self.coexact, self.harmonic))


def hodge_decomposition(
    mesh: Mesh,
    omega: Float[ArrayLike, "ne *k"],
    *,
    dual: str = "voronoi",
    solver: str = "auto",
    throw: bool = True,
) -> HodgeDecomposition | Solution:
    r"""Split a 1-form into its exact, co-exact and harmonic parts, `omega = d alpha + delta beta + gamma`.

    $$\omega = d\alpha + \delta\beta + \gamma, \qquad d_0^\top \star_1 d_0 \, \alpha = d_0^\top \star_1 \omega, \qquad \delta\beta = \star_1^{-1} d_1^\top \tilde\beta$$

    `d alpha` minimises `|omega - d alpha|_{*1}` over 0-forms (`d0^T *1 d0 alpha = d0^T *1 omega`),
    `delta beta = *1^{-1} d1^T beta~` solves `d1 delta beta = d1 omega`, and `gamma` is the rest,
    closed and co-closed. How the co-exact part is found without the (indefinite) face system
    `d1 *1^{-1} d1^T`: module docstring.

    Args:
        mesh: a consistently oriented triangle mesh (closed or with boundary, any genus, several
            components); `MeshDataError` otherwise.
        omega: `(ne,)` 1-form on `mesh.edges` (integrals along each edge from its lower to its higher
            vertex index), or `(ne, k)` for `k` forms at once.
        dual: the Hodge star `*1` (`ddgjax.dec.hodge1`), one of `ddgjax.DUAL_CELLS`: `"voronoi"`
            (default) and `"circumcentric"` are the cotan ratio `(cot a + cot b) / 2` of the DDG
            exercises; `"barycentric"` is positive on every mesh.
        solver: the backend of the Laplacian solve, one of `ddgjax.LINEAR_SOLVERS` (`"auto"`,
            `"cholesky"`, `"superlu"`, `"cg"`, `"pyamg"`).
        throw: raise on a failed step (default), or return the outcome.

    Returns:
        `HodgeDecomposition` with `exact`, `coexact`, `harmonic`, each the shape of `omega` (unpacks in
        that order); with `throw=False` a `ddgjax.Solution` holding it as `value`, the first failing
        step's outcome as `result` and `stats` `{"residual", "num_steps"}` of the Laplacian solve.

    Differentiable in `omega` and the vertex positions. Comparing with the DDG exercises
    (`test-decomp-soln.txt`): their edges are numbered and oriented by first appearance in the
    faces, so map with `mesh.edges` and a sign; the three parts do not depend on the global sign of
    `d0` or `d1`. References: module docstring; the DDG exercises' `HodgeDecomposition`.

    Examples:
        >>> import jax
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> torus = ddgjax.mesh.torus(n_major=24, n_minor=8)
        >>> omega = jax.random.normal(jax.random.key(0), (torus.n_edges,))
        >>> exact, coexact, harmonic = ddgjax.pde.hodge_decomposition(torus, omega)
        >>> bool(jnp.allclose(exact + coexact + harmonic, omega)), bool(jnp.allclose(ddgjax.dec.d1(torus) @ harmonic, 0.0))
        (True, True)
    """
    mesh = require_mesh("mesh", mesh)
    mesh.topology.require_oriented("ddgjax.pde.hodge_decomposition")
    check_choice("dual", dual, DUAL_CELLS)
    check_solver(solver)
    ne = mesh.n_edges
    if np.ndim(omega) not in (1, 2) or np.shape(omega)[0] != ne:
        raise DDGInputError(
            f"omega: expected shape ({ne},) or ({ne}, k), one value per edge of mesh.edges, got {np.shape(omega)}"
        )
    check_float_shape("omega", omega, np.shape(omega)[1:])
    omega = device_array(omega)
    if not jnp.issubdtype(omega.dtype, jnp.floating):
        omega = omega.astype(mesh.vertices.dtype)
    plan = vertex_plan(mesh)
    pins = DirichletData(mesh, None, None, (), plan.pattern)  # one vertex per component pinned to 0
    parts, result, stats = _decompose(
        mesh,
        omega,
        _device_cocycle_basis(mesh.topology),
        plan,
        dec_plan(mesh) if dual == "barycentric" else None,
        pins.plan,
        dual=dual,
        solver=solver,
    )
    return outcome(HodgeDecomposition(*parts), result, throw, stats)


@kernel(static_argnames=("dual", "solver"))
def _decompose(
    mesh: Mesh,
    omega: Float[Array, "ne *k"],
    cocycles: Float[Array, "ne g"],
    plan: TriangulationPlan,
    congruence_plan: CongruencePlan | None,
    pins: DirichletPlan | None,
    *,
    dual: str,
    solver: str,
) -> tuple[tuple[Array, Array, Array], RESULTS, dict[str, Array]]:
    """`((exact, coexact, harmonic), result, stats)` of `omega`, each part its shape (module docstring, steps 1-4).

    `mesh` comes without its topology: the tree-cotree `cocycles`, the vertex `plan`, the
    `congruence_plan` of `d0^T *1 d0` (barycentric `*1` only) and the `pins` of one vertex per
    component are passed in.
    """
    columns = omega.reshape(omega.shape[0], -1)
    n_columns = columns.shape[1]
    star = hodge_star_entries(mesh, degree=1, dual=dual)
    generators = cocycles.astype(columns.dtype)
    forms = jnp.concatenate([columns, generators], axis=1)
    derivative = d0(mesh)
    if dual == "barycentric":
        laplacian = congruence(derivative, star, plan.pattern, congruence_plan)
    else:  # d0^T *1 d0 for the cotan *1 is the cotan Laplacian, assembled faster from the lengths
        laplacian = cotan_laplacian_from_lengths_sq(face_edge_lengths_sq(mesh), plan)
    rhs = derivative.T @ (star[:, None] * forms)
    if pins is None:  # every vertex is pinned (isolated vertices only): every potential is 0
        potentials, solved = jnp.zeros_like(rhs), RESULTS.successful
        stats = {"residual": jnp.zeros((), rhs.dtype), "num_steps": jnp.zeros((), jnp.int32)}
    else:
        free_free, _ = dirichlet_blocks(laplacian, pins)
        solution = linear_solve(free_free, rhs[pins.free], solver=solver, throw=False)
        potentials = pins.join(solution.value, jnp.zeros((pins.fixed.shape[0], rhs.shape[1]), rhs.dtype))
        solved, stats = solution.result, solution.stats
    exact_forms = derivative @ potentials
    exact = exact_forms[:, :n_columns]
    remainder = columns - exact
    projected = RESULTS.successful
    if generators.shape[1]:
        basis = generators - exact_forms[:, n_columns:]  # closed and co-closed: the harmonic forms
        weighted = star[:, None] * basis
        coefficients = jnp.linalg.solve(basis.T @ weighted, weighted.T @ remainder)
        harmonic = basis @ coefficients
        # A singular Gram matrix (*1 vanishing on the harmonic forms) leaves no finite projection.
        projected = RESULTS.where(jnp.all(jnp.isfinite(coefficients)), RESULTS.successful, RESULTS.singular)
    else:
        harmonic = jnp.zeros_like(remainder)
    parts = tuple(part.reshape(omega.shape) for part in (exact, remainder - harmonic, harmonic))
    return parts, first_failure(solved, projected), stats


_COCYCLES: "weakref.WeakKeyDictionary[MeshTopology, np.ndarray]" = weakref.WeakKeyDictionary()


def closed_cocycle_basis(topology: MeshTopology) -> np.ndarray:
    """Closed 1-forms whose classes are a basis of the first cohomology, `(ne, k)` with entries in {-1, 0, 1}.

    Tree-cotree (Eppstein 2003): a spanning forest `T` of the vertex graph, then a spanning forest `C`
    of the dual graph on the edges not in `T` (faces are its nodes; each component with boundary gets
    one more node, the "outside", that its boundary edges join). Each of the `k` edges `x` in neither
    closes one loop in the dual forest; `eta_x` is +-1 on the primal edges that loop crosses, signed so
    that every face it passes is entered once and left once, hence `d1 eta_x = 0`. The primal loop of
    `x` in `T + x` crosses only `eta_x`'s support among all the `eta`, so their classes are independent;
    there are `k = 2 g` per closed component and `2 g + b - 1` per component with `b` boundary loops,
    the first Betti number, so they are a basis. Host NumPy / SciPy, once per connectivity (cached);
    needs consistently oriented faces.
    """
    basis = _COCYCLES.get(topology)
    if basis is None:
        basis = _COCYCLES[topology] = _tree_cotree_cocycles(topology)
    return basis


# The same basis on the device, so an eager call does not transfer it again.
_DEVICE_COCYCLES: "weakref.WeakKeyDictionary[MeshTopology, Array]" = weakref.WeakKeyDictionary()


def _device_cocycle_basis(topology: MeshTopology) -> Float[Array, "ne k"]:
    """`closed_cocycle_basis(topology)` as a device array (cached per connectivity)."""
    basis = _DEVICE_COCYCLES.get(topology)
    if basis is None:
        with jax.ensure_compile_time_eval():  # host data even when a caller's jit traces this call (it is cached)
            basis = _DEVICE_COCYCLES[topology] = device_array(closed_cocycle_basis(topology))
    return basis


def _tree_cotree_cocycles(topology: MeshTopology) -> np.ndarray:
    nv, ne, nf = topology.n_vertices, topology.n_edges, topology.n_faces
    edges = topology.edges.astype(np.int64)
    keys = edges[:, 0] * nv + edges[:, 1]  # ascending: edges are sorted lexicographically
    primal = sp.coo_matrix((np.ones(ne), (edges[:, 0], edges[:, 1])), shape=(nv, nv)).tocsr()
    forest = csgraph.minimum_spanning_tree(primal).tocoo()  # unit weights: any spanning forest
    low, high = np.minimum(forest.row, forest.col), np.maximum(forest.row, forest.col)
    in_tree = np.zeros(ne, dtype=bool)
    in_tree[np.searchsorted(keys, low.astype(np.int64) * nv + high)] = True

    # Dual nodes: faces 0..nf-1, the outside of component c at nf + c, one root at nf + n_components
    # joined to the first face of every component (so one breadth-first search spans the forest).
    components = topology.face_components.astype(np.int64)
    n_components = topology.n_components
    root = nf + n_components
    first_face = np.full(n_components, nf, dtype=np.int64)
    np.minimum.at(first_face, components, np.arange(nf))
    faces_of_edge = topology.edge_faces[:, :2].astype(np.int64)
    near = faces_of_edge[:, 0]
    far = np.where(faces_of_edge[:, 1] >= 0, faces_of_edge[:, 1], nf + components[near])
    sign_near = topology.face_edge_signs[near, topology.edge_face_corners[:, 0]].astype(np.int64)
    dual_edges = np.flatnonzero(~in_tree)
    n_nodes = root + 1
    graph = sp.coo_matrix(
        (
            np.ones(dual_edges.size + n_components),
            (np.concatenate([near[dual_edges], np.full(n_components, root)]), np.concatenate([far[dual_edges], first_face])),
        ),
        shape=(n_nodes, n_nodes),
    ).tocsr()
    _, parent = csgraph.breadth_first_order(graph, root, directed=False, return_predecessors=True)
    parent = parent.astype(np.int64)

    # The edge each node crosses to its parent (pairs may repeat: a face with two outside edges, two
    # faces sharing two edges; any one of the repeated edges serves), and the sign of crossing it.
    child = np.flatnonzero((parent >= 0) & (parent != root))
    pair_keys = np.minimum(near, far)[dual_edges] * n_nodes + np.maximum(near, far)[dual_edges]
    order = np.argsort(pair_keys, kind="stable")
    query = np.minimum(child, parent[child]) * n_nodes + np.maximum(child, parent[child])
    up_edge = np.full(n_nodes, -1, dtype=np.int64)
    up_edge[child] = dual_edges[order[np.searchsorted(pair_keys[order], query)]]
    in_cotree = np.zeros(ne, dtype=bool)
    in_cotree[up_edge[child]] = True
    # Crossing e out of the face n adds s_{n,e} (n's own traversal of e); out of an outside node into
    # the face p, -s_{p,e}: every face on a loop then sees +1 where it is left and -1 where entered.
    up_sign = np.zeros(n_nodes, dtype=np.int64)
    up_sign[child] = sign_near[up_edge[child]] * np.where(child == near[up_edge[child]], 1, -1)

    loops = np.flatnonzero(~in_tree & ~in_cotree)
    basis = np.zeros((ne, loops.size))
    generator = np.arange(loops.size)
    basis[loops, generator] = sign_near[loops]  # near -> far across x, then far -> root -> near
    walkers = np.concatenate([far[loops], near[loops]])
    weights = np.concatenate([np.ones(loops.size), -np.ones(loops.size)])
    owners = np.concatenate([generator, generator])
    while True:
        moving = up_edge[walkers] >= 0
        if not moving.any():
            break
        walkers, weights, owners = walkers[moving], weights[moving], owners[moving]
        np.add.at(basis, (up_edge[walkers], owners), weights * up_sign[walkers])
        walkers = parent[walkers]
    basis.setflags(write=False)
    return basis
