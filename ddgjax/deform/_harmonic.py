"""k-harmonic deformation: the displacement that minimises `D^T Q D`, `Q = L (M^{-1} L)^{k-1}`, with handles prescribed.

The k-harmonic operator `Q = L (M^{-1} L)^{k-1}` (`k = 1` harmonic, `2` biharmonic, `3` triharmonic)
is what libigl's `harmonic_matrix` builds: `L` the PSD cotan Laplacian, `M` a lumped mass matrix
(`M^{-1} L` is the pointwise Laplace-Beltrami operator up to sign). For `k >= 2` it has a wider
pattern (the 2-ring for `k = 2`, the 3-ring for `k = 3`), so it is assembled as a sparse product
`A diag(w) B` on a pattern found once per connectivity on the host (`_Product`): each product
`A_ij w_j B_jl` lands in a fixed slot, summed by a sorted `segment_sum`, and `A` / `B`'s values are
read by `ddgjax.sparse.gather_sum` (reverse pass a gather). The alternative, the mixed system in `(D, M^{-1} L D)`
(Jacobson et al. 2010), is indefinite (no Cholesky, and its own block pattern); `Q` restricted
to the free vertices is symmetric positive definite, so the Dirichlet machinery of `ddgjax.sparse`
(`dirichlet_plan` / `dirichlet_blocks`) and the Cholesky backend of `ddgjax.solve.linear_solve` serve
it unchanged, and the solve differentiates implicitly in `Q`'s values, hence in the rest positions.
"""

from __future__ import annotations

import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError
from .._numerics import safe_reciprocal
from .._options import LUMPED_MASS_MATRICES, check_mass, check_solver
from .._results import RESULTS, Solution, outcome
from ..discretization import discretize
from ..discretization.internal import DirichletData
from ..laplacian.internal import vertex_plan
from ..mesh import Mesh, MeshTopology, require_mesh
from ..solve import linear_solve
from ..sparse import DirichletPlan, SparseMatrix, SparsityPattern, dirichlet_blocks, gather_sum


def biharmonic_deformation(
    mesh: Mesh,
    *,
    fixed_vertices: Int[ArrayLike, " n_fixed"],
    fixed_values: Float[ArrayLike, "n_fixed 3"],
    order: int = 2,
    mass: str = "voronoi",
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "nv 3"] | Solution:
    r"""New vertex positions `V + D`, the displacement `D` k-harmonic away from the handles.

    $$\min_D \operatorname{tr}(D^\top Q D), \qquad Q = L (M^{-1} L)^{k-1}$$

    (`L` the PSD cotan Laplacian, `M`
    the lumped mass matrix `mass`) subject to `D[fixed_vertices] = fixed_values - V[fixed_vertices]`:
    `Q_ff D_f = -Q_fc D_c` on the free vertices `f`. `k = 1` is harmonic, `k = 2` (default)
    biharmonic (the discrete Laplacian energy $\int \lVert \Delta D \rVert^2 \, dA$, `C^1` at the handles), `k = 3`
    triharmonic. Solving for the displacement rather than the positions keeps the surface's detail:
    `fixed_values = V[fixed_vertices]` returns `V`, and a translation of every handle translates the
    whole mesh (the constants are k-harmonic); a rotation of the handles is not reproduced exactly.
    Differentiable in `fixed_values` and in the rest positions (through `L` and `M`; the solve
    differentiates implicitly), under `jit`, `grad` and `vmap`.

    Args:
        mesh: a triangle mesh whose every connected component holds at least one handle (vertices used
            by no face stay where they are).
        fixed_vertices: `(n_fixed,)` distinct vertex indices, the handles (concrete, host data).
        fixed_values: `(n_fixed, 3)` their new positions.
        order: the order `k`, an integer `>= 1` (static; the vocabulary's `order=`, libigl's `k`).
        mass: the lumped mass matrix `M`, one of `ddgjax.LUMPED_MASS_MATRICES`: `"voronoi"` (default,
            libigl's) or `"barycentric"`; unused for `k = 1`.
        solver: the backend of the linear solve, one of `ddgjax.LINEAR_SOLVERS`.
        throw: raise on a failed solve (default), or return the outcome.

    Returns:
        `(nv, 3)` new positions, equal to `fixed_values` at the handles; with `throw=False` a
        `ddgjax.Solution` holding them as `value`, the solve's outcome as `result` and `stats`
        `{"residual": |A x - b| / |b|, "num_steps": CG iterations}` of the free-free system.

    References: A. Jacobson, E. Tosun, O. Sorkine, D. Zorin, "Mixed finite elements for variational
    surface modeling", SGP 2010; M. Botsch, O. Sorkine, "On linear variational surface deformation
    methods", IEEE TVCG 2008. libigl (tutorial 401, "deformation field"):
    `V + igl.harmonic(V, F, b, bc - V[b], k)`. Tutorial 401's other mode, `igl.harmonic(V, F, b, bc, k)`
    on the positions themselves, is `biharmonic_deformation` plus `igl.harmonic(V, F, b, V[b], k) - V`:
    the two agree only where the rest positions are k-harmonic (a flat mesh for `k = 1`); otherwise
    the positions' version smooths the surface's detail away.

    Examples:
        >>> import numpy as np
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> square = ddgjax.mesh.grid(6, 6)
        >>> corners = np.array([0, 6, 42, 48])
        >>> V, up = square.vertices, jnp.array([0.0, 0.0, 0.5])
        >>> moved = ddgjax.deform.biharmonic_deformation(square, fixed_vertices=corners, fixed_values=V[corners] + up)
        >>> moved.shape, bool(jnp.allclose(moved, V + up))  # a translation of the handles moves everything
        ((49, 3), True)
    """
    mesh = require_mesh("mesh", mesh)
    k = _check_order(order)
    check_mass(mass, LUMPED_MASS_MATRICES)
    check_solver(solver)
    vertices, values = _check_handles(mesh, fixed_vertices, fixed_values)
    operator = _operator_plan(mesh, k)
    dirichlet = DirichletData(mesh, vertices, values, (3,), operator.pattern)
    floating = np.flatnonzero(np.asarray(dirichlet.floating))
    if floating.size:
        raise DDGInputError(
            f"fixed_vertices: every connected component needs a handle, the one of vertex {int(floating[0])} has none "
            "(its displacement would be determined only up to a constant); add one of its vertices"
        )
    positions = mesh.vertices
    dtype = jnp.result_type(positions.dtype, dirichlet.values.dtype)
    if dirichlet.plan is None:  # every vertex is a handle (or unused): nothing to solve
        value = positions.astype(dtype).at[dirichlet.vertices].set(dirichlet.values.astype(dtype))
        stats = {"residual": jnp.zeros((), dtype), "num_steps": jnp.zeros((), jnp.int32)}
        return outcome(value, RESULTS.successful, throw, stats)
    # `Q_ff D_f = -Q_fc D_c` from one program, `linear_solve` (its checks on the host, outside every
    # program) and one more joining `V + D`, so each can be kept across processes (`ddgjax._program_store`);
    # under `jit` / `grad` / `vmap` all of it is traced into the caller's program.
    discretization = discretize(mesh, mass=mass)
    free_free, rhs, held = _system(
        mesh,
        discretization.laplacian,
        discretization.mass,
        operator,
        dirichlet.values.astype(dtype),
        dirichlet.plan,
        n_pinned=dirichlet.n_pinned,
    )
    solution = linear_solve(free_free, rhs, solver=solver, throw=False)
    value, result, stats = _deformed(mesh, solution.value, held, dirichlet.plan), solution.result, solution.stats
    return outcome(value, result, throw, stats)


class _Product(eqx.Module):
    """The product `C = A diag(w) B` of two square matrices onto `C`'s pattern (host plan from `_product`).

    Product `p` is `A_ij w_j B_jl` for a stored `(i, j)` of `A` and `(j, l)` of `B`; products are in
    the order of their slot of `C`.

    Attributes:
        pattern: the pattern of `C` (every `(i, l)` some product reaches).
        slots: `(p,)` the slot of `C` of each product, ascending.
        a_source, b_source: `(p, 1)` the slot of `A` / `B` each product reads.
        a_readers, b_readers: `(nnz_a, r)` / `(nnz_b, r)` their transposes, padded with `p`
            (`gather_sum`'s reverse pass).
    """

    pattern: SparsityPattern
    slots: Int[Array, " p"]
    a_source: Int[Array, "p 1"]
    a_readers: Int[Array, "nnz_a r"]
    b_source: Int[Array, "p 1"]
    b_readers: Int[Array, "nnz_b s"]

    def __call__(self, a: SparseMatrix, weights: Float[Array, " n"], b: SparseMatrix) -> SparseMatrix:
        """`A diag(weights) B` on `pattern`, flagged symmetric PSD (the caller's promise: `Q` is)."""
        scaled = b.values * weights[b.pattern.rows]  # diag(w) B: row j of B times w_j
        products = gather_sum(a.values, self.a_source, self.a_readers) * gather_sum(scaled, self.b_source, self.b_readers)
        values = jax.ops.segment_sum(products, self.slots, num_segments=self.pattern.nnz, indices_are_sorted=True)
        return SparseMatrix(values, self.pattern, symmetric=True, positive_semidefinite=True)


def _product(a: SparsityPattern, b: SparsityPattern) -> _Product:
    """The `_Product` plan of `A diag(w) B` for square patterns `a`, `b` (NumPy, once per connectivity)."""
    a_rows, a_cols, a_slots = a.entries()
    b_rows, b_cols, b_slots = b.entries()  # CSR order: rows ascending
    b_start = np.searchsorted(b_rows, np.arange(b.shape[0] + 1))
    counts = b_start[a_cols + 1] - b_start[a_cols]  # entries of B in row j, for each entry (i, j) of A
    first = np.repeat(np.arange(a_rows.size), counts)
    pair_b = np.repeat(b_start[a_cols], counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    pattern, slot = SparsityPattern.from_coo(a_rows[first], b_cols[pair_b], (a.shape[0], b.shape[1]))
    order = np.argsort(slot, kind="stable")
    a_source, b_source = a_slots[first][order], b_slots[pair_b][order]
    return _Product(
        pattern=pattern,
        slots=device_array(slot[order], dtype=jnp.int32),
        a_source=device_array(a_source[:, None], dtype=jnp.int32),
        a_readers=device_array(_readers(a_source, a.nnz), dtype=jnp.int32),
        b_source=device_array(b_source[:, None], dtype=jnp.int32),
        b_readers=device_array(_readers(b_source, b.nnz), dtype=jnp.int32),
    )


def _readers(source: np.ndarray, n: int) -> np.ndarray:
    """`(n, r)`: for each slot, the positions of `source` that read it, padded with `source.size`."""
    order = np.argsort(source, kind="stable")
    counts = np.bincount(source, minlength=n)
    column = np.arange(source.size) - np.repeat(np.cumsum(counts) - counts, counts)
    readers = np.full((n, max(int(counts.max(initial=0)), 1)), source.size, dtype=np.int64)
    readers[source[order], column] = order
    return readers


class _OperatorPlan(eqx.Module):
    """How `Q = L (M^{-1} L)^{k-1}` is assembled: `Q_1 = L`, `Q_{p+1} = Q_p M^{-1} L` (`products`), on `pattern`."""

    pattern: SparsityPattern
    products: tuple[_Product, ...]


# Per connectivity, the plan of each order asked for (host work: the products' patterns and slots).
_OPERATOR_PLANS: "weakref.WeakKeyDictionary[MeshTopology, dict[int, _OperatorPlan]]" = weakref.WeakKeyDictionary()


def _operator_plan(mesh: Mesh, k: int) -> _OperatorPlan:
    """The `_OperatorPlan` of order `k` on `mesh`'s connectivity (built on first use, then cached)."""
    plans = _OPERATOR_PLANS.setdefault(mesh.topology, {})
    if k not in plans:
        laplacian = vertex_plan(mesh).pattern
        # Host work even inside a caller's trace: it depends on the connectivity only.
        with jax.ensure_compile_time_eval():
            products, pattern = [], laplacian
            for _ in range(k - 1):
                products.append(_product(pattern, laplacian))
                pattern = products[-1].pattern
            plans[k] = _OperatorPlan(pattern=pattern, products=tuple(products))
    return plans[k]


@kernel(static_argnames=("n_pinned",))
def _system(
    mesh: Mesh,
    laplacian: SparseMatrix,
    mass_matrix_: SparseMatrix,
    operator: _OperatorPlan,
    values: Float[Array, "n_fixed 3"],
    blocks: DirichletPlan,
    *,
    n_pinned: int,
) -> tuple[SparseMatrix, Float[Array, "n_free 3"], Float[Array, "n_held 3"]]:
    """`(Q_ff, -Q_fc D_c, D_c)`: the free-free block of `Q = L (M^{-1} L)^{k-1}` (`L`, `M` the mesh's
    discretisation), the right-hand side, and the held displacement `D_c` (`values - V` at the handles,
    then `n_pinned` zeros)."""
    positions = mesh.vertices.astype(values.dtype)
    operator_matrix = laplacian
    if operator.products:
        # Unused vertices have no area; their rows of L are empty, so any weight serves (0).
        inverse_areas = safe_reciprocal(mass_matrix_.diagonal())
        for product in operator.products:
            operator_matrix = product(operator_matrix, inverse_areas, laplacian)
    handles = blocks.fixed[: values.shape[0]]
    fixed_displacement = jnp.concatenate([values - positions[handles], jnp.zeros((n_pinned, 3), values.dtype)])
    free_free, free_fixed = dirichlet_blocks(operator_matrix, blocks)
    return free_free, -(free_fixed @ fixed_displacement), fixed_displacement


@kernel
def _deformed(
    mesh: Mesh, free_displacement: Float[Array, "n_free 3"], fixed_displacement: Float[Array, "n_held 3"], blocks: DirichletPlan
) -> Float[Array, "nv 3"]:
    """`V + D`, `D` joined from its free and held parts."""
    return mesh.vertices.astype(fixed_displacement.dtype) + blocks.join(free_displacement, fixed_displacement)


def _check_order(k) -> int:
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise DDGInputError(f"order: expected an integer >= 1 (1 harmonic, 2 biharmonic, 3 triharmonic), got {k!r}")
    return int(k)


def _check_handles(mesh: Mesh, fixed_vertices, fixed_values) -> tuple[ArrayLike, Array]:
    """The handles as given, refused when there are none or `fixed_values` is not `(n_fixed, 3)`.

    Indices (range, repeats, dtype) are `DirichletData`'s checks."""
    if fixed_vertices is None or np.size(fixed_vertices) == 0:
        raise DDGInputError("fixed_vertices: expected at least one handle vertex, got none")
    n_fixed = np.shape(fixed_vertices)[0] if np.ndim(fixed_vertices) == 1 else None
    if fixed_values is None or n_fixed is None or np.shape(fixed_values) != (n_fixed, 3):
        raise DDGInputError(
            f"fixed_values: expected shape ({n_fixed if n_fixed is not None else 'n_fixed'}, 3), the new position of "
            f"each vertex of fixed_vertices (a 1-d index array), got {None if fixed_values is None else np.shape(fixed_values)}"
        )
    values = device_array(fixed_values)  # host data moved without an eager program
    if not jnp.issubdtype(values.dtype, jnp.floating):
        values = device_array(fixed_values, mesh.vertices.dtype)
    return fixed_vertices, values
