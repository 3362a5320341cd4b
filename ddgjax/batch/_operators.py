"""Batched geometry and operators on a `MeshBatch`: per mesh, the single-mesh functions of ddgjax.

Each function equals, mesh by mesh, its single-mesh namesake (`ddgjax.mesh.face_areas`,
`face_normals`, `vertex_normals`, `ddgjax.laplacian.laplacian_apply`, `dirichlet_energy`,
`mass_matrix` (as `lumped_mass` and `mass_apply`), `ddgjax.dec.gradient`) on the unpadded rows, with the same conventions (the PSD
weak cotan Laplacian `(L u)_i = 1/2 sum_j (cot a_ij + cot b_ij)(u_i - u_j)`, libigl corner order),
and gives exactly 0 on padded vertices and faces. One per-mesh body runs over the batch axis:
`jax.vmap`-ped on accelerators (the batch shards along axis 0 like any `(B, ...)` pytree), one mesh
after another (`jax.lax.map`) on CPU, where the whole batch's gathered corners would outgrow the
scratch memory XLA:CPU reuses between calls (about 4x slower for 16 meshes of up to 20k vertices).

Layout (the reason for the plan of `MeshBatch`): per face, one gather of its three corners'
positions (and values), arithmetic coordinate by coordinate on `(nfp,)` arrays as the single-mesh
kernels do, and one fixed gather of the per-corner results into the rows of `vertex_corners` (eight
corners per row; a high-valence vertex's overflow rows are folded into it with one sorted
`segment_sum` of a few rows). Both gathers are `ddgjax.sparse.gather_sum`, whose transpose is the
other gather, so the reverse pass has no scatter-add beyond the overflow rows' fold. The Laplacian,
as the single-mesh `laplacian_apply`, puts each corner's `cot / 2` on the directed edges `i -> j`
of its opposite edge (`slot_corners`, a `gather_sum`) and sums `W_ij (u_i - u_j)` over each
vertex's first six neighbours (`vertex_neighbors`, slot-major ELL) and over the overflow edges (a
sorted `segment_sum`, as the COO tail of the single-mesh pattern): an `(nvp, k)` `u` is read once
per directed edge, not materialised per corner. Every table has a constant width and overflow
lengths fixed by `(nvp, nfp)`, so one program serves a bucket whatever its meshes' structure.

Every function compiles at top level with `ddgjax._compile.kernel` (one program per bucket and
option, the most recent kept) and is traced into a caller's `jit` / `grad` / `vmap` otherwise.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_choice
from .._indexing import take_rows_or_zero
from .._numerics import safe_div, safe_norm, safe_normalize, unsigned_angle
from .._options import LUMPED_MASS_MATRICES, check_mass
from ..laplacian.internal import dirichlet_energy_length_weights
from ..mesh import corner_cotangents_from_lengths_sq, corner_dual_areas_from_lengths_sq
from ..mesh.internal import face_geometry_from_corners
from ..sparse import gather_sum
from ._batch import MeshBatch, require_batch

_NORMAL_WEIGHTINGS = ("area", "angle", "uniform")


# ---- per-mesh bodies (one mesh's padded arrays; vmapped over the batch) ----


class _Faces:
    """One mesh's padded faces as gathers: corners from vertices and back (module docstring)."""

    def __init__(self, face_mask: Bool[Array, " nfp"], corners: tuple, edges: tuple):
        self.face_mask = face_mask
        self.n_faces = face_mask.shape[0]
        # (vertex_corners (nvp + R, 8), corner_rows (nfp, 3), overflow_vertices (R,))
        self.vertex_corners, corner_rows, self.overflow_vertices = corners
        self.corner_rows = corner_rows.reshape(-1, 1)
        self.edges = edges  # (vertex_neighbors (6, nvp), overflow_edges (K, 2), slot_corners, corner_slots)

    def _has_overflow_rows(self) -> Bool[Array, ""]:
        """Whether a vertex of this mesh continues in an overflow row (valence above eight; padding rows read `nvp`)."""
        return self.overflow_vertices[0] < self.vertex_corners.shape[0] - self.overflow_vertices.shape[0]

    def at_corners(self, x: Float[Array, "nvp *rest"]) -> Float[Array, "nfp 3 *rest"]:
        """`x[F]` (zeros on padding faces).

        With overflow rows, the gather reads `x` extended by its overflow rows' vertices (a sorted
        gather of `R` rows, whose transpose is the fold of `to_vertices`); without (`lax.cond`, so
        meshes of low valence skip it), every corner's row is its vertex and `x` is read as it is.
        """
        n = x.shape[0]

        def with_overflow(x):
            rows = jnp.concatenate([x, _take_sorted(x, self.overflow_vertices)])
            return gather_sum(rows, self.corner_rows, self.vertex_corners)

        def without_overflow(x):
            return gather_sum(x, self.corner_rows, self.vertex_corners[:n])

        values = jax.lax.cond(self._has_overflow_rows(), with_overflow, without_overflow, x)
        return values.reshape((self.n_faces, 3) + x.shape[1:])

    def to_vertices(self, corner_values: Float[Array, "nfp 3 *rest"]) -> Float[Array, "nvp *rest"]:
        """`sum` of the per-corner values at each vertex (0 on padded vertices); overflow rows fold into their vertex."""
        flat = corner_values.reshape((3 * self.n_faces,) + corner_values.shape[2:])
        n = self.vertex_corners.shape[0] - self.overflow_vertices.shape[0]

        def with_overflow(flat):
            rows = gather_sum(flat, self.vertex_corners, self.corner_rows)
            return rows[:n] + _sum_sorted(rows[n:], self.overflow_vertices, n)

        def without_overflow(flat):
            return gather_sum(flat, self.vertex_corners[:n], self.corner_rows)

        return jax.lax.cond(self._has_overflow_rows(), with_overflow, without_overflow, flat)

    def edge_sum(self, weights: Float[Array, "nfp 3"], x: Float[Array, "nvp *k"]) -> Float[Array, "nvp *k"]:
        """`sum_j W_ij (x_i - x_j)` per vertex, `W_ij` the sum of `weights` at the corners opposite the edge `ij`.

        The per-corner weights land on the directed-edge slots with one fixed gather (`gather_sum`),
        then each vertex gathers its first six neighbours' rows of `x` (slot-major ELL: each slot
        column is contiguous and `x_i` needs no gather; a padding slot has weight 0 and reads 0) and
        the overflow edges add theirs with one sorted `segment_sum`, as the single-mesh
        `laplacian_apply` does, so an `(nvp, k)` `x` is read once per directed edge. A mesh without
        overflow edges (every vertex of degree 6 or less) skips their slots (`lax.cond`: on CPU, where
        the batch is mapped mesh by mesh, regular meshes do not pay for the overflow part).
        """
        neighbors, overflow_edges, slot_corners, corner_slots = self.edges
        width, n = neighbors.shape
        tails, heads = overflow_edges[:, 0], overflow_edges[:, 1]
        extra = (None,) * (x.ndim - 1)

        def ell(slot_weights, x):
            ell_weights = slot_weights[: width * n].reshape(width, n)
            result = jnp.zeros_like(x)
            for s in range(width):
                result = result + ell_weights[(s, slice(None), *extra)] * (x - take_rows_or_zero(x, neighbors[s]))
            return result

        def with_overflow(weights, x):
            slot_weights = gather_sum(weights.reshape(-1), slot_corners, corner_slots)
            differences = slot_weights[width * n :][(slice(None), *extra)] * (
                _take_sorted(x, tails) - take_rows_or_zero(x, heads)
            )
            return ell(slot_weights, x) + _sum_sorted(differences, tails, n)

        def without_overflow(weights, x):
            # Every corner's slots lie in the ELL part here, so its rows alone are the whole incidence.
            return ell(gather_sum(weights.reshape(-1), slot_corners[: width * n], corner_slots), x)

        return jax.lax.cond(tails[0] < n, with_overflow, without_overflow, weights, x)

    def geometry(self, vertices: Float[Array, "nvp 3"]):
        """Edge coordinates `e[k][c]` (edge opposite corner `k`), squared lengths `(nfp, 3)`, areas `(nfp,)`, corner positions."""
        corners = self.at_corners(vertices)
        return (*face_geometry_from_corners(corners), corners)  # as ddgjax.mesh.face_areas / face_edge_lengths_sq


def _take_sorted(x: Float[Array, "n *rest"], index: Int[Array, " r"]) -> Float[Array, "r *rest"]:
    """`x[index]` for increasing `index`, 0 where `index >= n` (padding); its transpose is `_sum_sorted`."""
    return x.at[index].get(mode="fill", fill_value=0, indices_are_sorted=True)


def _sum_sorted(values: Float[Array, "r *rest"], index: Int[Array, " r"], n: int) -> Float[Array, "n *rest"]:
    """`sum` of `values` per `index` (increasing; `index >= n` dropped): a sorted `segment_sum` of the few overflow entries."""
    return jax.ops.segment_sum(values, index, num_segments=n, indices_are_sorted=True)


def _area_vectors(corners: Float[Array, "nfp 3 3"]) -> Float[Array, "nfp 3"]:
    """`(p1 - p0) x (p2 - p0) / 2`, as `ddgjax.mesh.face_area_vectors`."""
    return 0.5 * jnp.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])


def _laplacian_one(faces: _Faces, vertices, u):
    _, lengths_sq, areas, _ = faces.geometry(vertices)
    half_cotangents = 0.5 * corner_cotangents_from_lengths_sq(lengths_sq, areas=areas)
    return faces.edge_sum(half_cotangents, u)


def _energy_vertex_gradient_one(faces: _Faces, vertices, u):
    """`grad_V E` of `E = 1/2 u^T L u` in closed form: `sum_{j ~ i} 2 mu_ij (p_i - p_j)`, `mu_ij = dE / d l_ij^2`.

    Per face, with `d_k = u_{k+1} - u_{k+2}`, `D = sum_k d_k^2` and `S = sum_k cot_k d_k^2`,
    `2 dE_f / d l_m^2 = (D - 2 d_m^2 - cot_m S) / (8 A)` (the derivation is
    `ddgjax.laplacian.dirichlet_energy`'s; zero-area faces give 0). Columns of `u` add up.
    """
    _, lengths_sq, areas, _ = faces.geometry(vertices)
    # edge_sum takes W_ij (x_i - x_j), the single-mesh slot sum W_ij (x_j - x_i): the opposite sign.
    return faces.edge_sum(-dirichlet_energy_length_weights(lengths_sq, areas, faces.at_corners(u)), vertices)


def _vmapped(body):
    """`body(faces: _Faces, *per_mesh_args)` over the batch: `f(batch, *batched_args)` (module docstring: map or vmap)."""

    def over_batch(batch: MeshBatch, *args):
        def one(vertices, face_mask, vertex_corners, corner_rows, overflow_vertices, *rest):
            edges, rest = rest[:4], rest[4:]
            return body(_Faces(face_mask, (vertex_corners, corner_rows, overflow_vertices), edges), vertices, *rest)

        plan = (
            batch.vertex_corners,
            batch.corner_rows,
            batch.overflow_vertices,
            batch.vertex_neighbors,
            batch.overflow_edges,
            batch.slot_corners,
            batch.corner_slots,
        )
        arrays = (batch.vertices, batch.face_mask, *plan, *args)
        if jax.default_backend() == "cpu":
            # One mesh at a time: XLA:CPU materialises the corner gathers, and a whole batch's scratch memory
            # passes glibc's mmap threshold (fresh pages faulted in on every call; ddgjax.laplacian._cotan).
            return jax.lax.map(lambda per_mesh: one(*per_mesh), arrays)
        return jax.vmap(one)(*arrays)

    return over_batch


# ---- checks ----


def _vertex_values(batch: MeshBatch, u, *, name: str = "u", columns: bool = True) -> Float[Array, "B nvp *k"]:
    """`u` as a floating JAX array of shape `(B, nvp)` (or `(B, nvp, k)` if `columns`), else `DDGInputError`."""
    b, nvp = batch.batch_size, batch.n_padded_vertices
    ndims = (2, 3) if columns else (2,)
    if np.ndim(u) not in ndims or np.shape(u)[:2] != (b, nvp):
        expected = f"({b}, {nvp})" + (f" or ({b}, {nvp}, k)" if columns else "")
        raise DDGInputError(f"{name}: expected shape {expected} (pad_vertex_values pads per-mesh values), got {np.shape(u)}")
    array = device_array(u)
    if not jnp.issubdtype(array.dtype, jnp.floating):
        array = array.astype(batch.vertices.dtype)
    return array


# ---- public operators ----

# `batch` is annotated loosely on purpose: a mesh or an array passed instead gets `require_batch`'s
# `DDGInputError` (saying what to build) rather than a run-time type-checker's message.
AnyBatch = object


def laplacian_apply(batch: AnyBatch, u: Float[ArrayLike, "B nvp *k"], /) -> Float[Array, "B nvp *k"]:
    r"""Matrix-free `L u` per mesh, `(B, nvp)` or `(B, nvp, k)`: `ddgjax.laplacian.laplacian_apply` on each mesh.

    $$\sum_j L_{ij} u_j = \tfrac12 \sum_{j \sim i} (\cot\alpha_{ij} + \cot\beta_{ij})(u_i - u_j),$$

    the PSD weak (integrated) cotan
    Laplacian (DESIGN.md), with the cotangents from the squared edge lengths and the cross-product
    area (`ddgjax.mesh.corner_cotangents_from_lengths_sq`), summed per corner and gathered into the
    vertices (module docstring). Padded vertices get 0; values of `u` there are never read.
    Differentiable in `u` and the positions (forward and reverse, no scatter-add), jit / vmap.

    Args:
        batch: `MeshBatch`.
        u: `(B, nvp)` or `(B, nvp, k)` padded vertex values (`pad_vertex_values`).

    Returns:
        `L u` per mesh, the shape of `u`. PyTorch3D: `cot_laplacian` (with the opposite sign and
        without the 1/2, `ddgjax.laplacian.to_pytorch3d_cot_laplacian`) on the packed mesh.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> meshes = [ddgjax.mesh.icosphere(1), ddgjax.mesh.icosphere(2)]
        >>> batch = ddgjax.batch.MeshBatch.from_meshes(meshes)
        >>> Lz = ddgjax.batch.laplacian_apply(batch, batch.vertices[..., 2])
        >>> one = ddgjax.laplacian.cotan_laplacian(meshes[1]) @ meshes[1].vertices[:, 2]
        >>> Lz.shape, bool(jnp.allclose(Lz[1, :162], one))
        ((2, 192), True)
    """
    batch = require_batch("batch", batch)
    return _laplacian(batch, _vertex_values(batch, u))


@kernel
def _laplacian(batch: MeshBatch, u: Float[Array, "B nvp *k"]) -> Float[Array, "B nvp *k"]:
    return _vmapped(_laplacian_one)(batch, u)


def dirichlet_energy(batch: AnyBatch, u: Float[ArrayLike, "B nvp *k"], /) -> Float[Array, " B"]:
    """Dirichlet energy `E_b = 1/2 u_b^T L_b u_b` of each mesh, `(B,)` (summed over columns of a `(B, nvp, k)` `u`).

    As `ddgjax.laplacian.dirichlet_energy` per mesh; differentiable in `u` (`grad_u E = L u`) and the
    positions. `jnp.sum(dirichlet_energy(batch, u))` is the loss whose gradient is each mesh's own.
    Reference: Pinkall & Polthier 1993. libigl: `0.5 * u @ (-igl.cotmatrix(V, F) @ u)`.

    Args:
        batch: `MeshBatch`.
        u: `(B, nvp)` or `(B, nvp, k)` padded vertex values (`pad_vertex_values`; positional-only).

    Returns:
        `(B,)` energies, one per mesh (padded vertices contribute nothing).
    """
    batch = require_batch("batch", batch)
    return _energy(batch, _vertex_values(batch, u))


@jax.custom_jvp
def _energy_values(batch: MeshBatch, u: Float[Array, "B nvp *k"]) -> Float[Array, " B"]:
    return _energy_and_applied(batch, u)[0]


def _energy_and_applied(batch: MeshBatch, u):
    applied = _vmapped(_laplacian_one)(batch, u)
    mask = batch.vertex_mask.reshape(batch.vertex_mask.shape + (1,) * (u.ndim - 2))
    axes = tuple(range(1, u.ndim))
    return 0.5 * jnp.sum(jnp.where(mask, u * applied, 0.0), axis=axes), applied, axes


def _energy_jvp(primals, tangents):
    """`dE_b = <L u, du>_b + <grad_V E, dV>_b`: a closed-form position gradient, so the reverse pass has no scatter-add.

    Symbolic zeros skip the term of an unperturbed argument (as `ddgjax.laplacian.dirichlet_energy`).
    """
    batch, u = primals
    d_batch, d_u = tangents
    energy, applied, axes = _energy_and_applied(batch, u)
    d_energy = jnp.zeros_like(energy)
    if not isinstance(d_u, SymbolicZero):
        d_energy = d_energy + jnp.sum(applied * d_u, axis=axes)
    if not isinstance(d_batch.vertices, SymbolicZero):
        gradient = _vmapped(_energy_vertex_gradient_one)(batch, u)
        d_energy = d_energy + jnp.sum(gradient * d_batch.vertices, axis=(1, 2))
    return energy, d_energy


_energy_values.defjvp(_energy_jvp, symbolic_zeros=True)
_energy = kernel(_energy_values)


def face_areas(batch: AnyBatch) -> Float[Array, "B nfp"]:
    """Area of each face, `(B, nfp)`, `|(p1 - p0) x (p2 - p0)| / 2` (`ddgjax.mesh.face_areas` per mesh); 0 on padding.

    Args:
        batch: `MeshBatch`.

    Returns:
        `(B, nfp)` areas, in the vertices' dtype; 0 on padded faces.
    """
    return _face_areas(require_batch("batch", batch))


@kernel
def _face_areas(batch: MeshBatch) -> Float[Array, "B nfp"]:
    return jnp.where(batch.face_mask, _vmapped(lambda faces, vertices: faces.geometry(vertices)[2])(batch), 0.0)


def face_normals(batch: AnyBatch) -> Float[Array, "B nfp 3"]:
    """Unit face normals, `(B, nfp, 3)` (`ddgjax.mesh.face_normals` per mesh); zero on zero-area and padding faces.

    Args:
        batch: `MeshBatch`.

    Returns:
        `(B, nfp, 3)` unit normals; zero rows on zero-area and padded faces.
    """
    return _face_normals(require_batch("batch", batch))


@kernel
def _face_normals(batch: MeshBatch) -> Float[Array, "B nfp 3"]:
    normals = _vmapped(lambda faces, vertices: safe_normalize(_area_vectors(faces.at_corners(vertices))))(batch)
    return jnp.where(batch.face_mask[..., None], normals, 0.0)


def vertex_normals(batch: AnyBatch, *, weighting: str = "area", normalize: bool = True) -> Float[Array, "B nvp 3"]:
    """Vertex normals, `(B, nvp, 3)`, as `ddgjax.mesh.vertex_normals(mesh, weighting=, normalize=)` per mesh.

    `n_i = sum_{f ni i} w_f N_f` with `w_f` the face area (`"area"`, default), the corner angle
    (`"angle"`) or 1 (`"uniform"`), then normalised unless `normalize=False`; zero on padded
    vertices. libigl: `per_vertex_normals`; PyTorch3D: `Meshes.verts_normals_padded()` (area weighted).

    Args:
        batch: `MeshBatch`.
        weighting: how the faces around a vertex are weighted: `"area"` (default), `"angle"` or `"uniform"`
            (keyword-only, static; as `ddgjax.mesh.vertex_normals`).
        normalize: whether to scale each sum to unit length (default `True`; keyword-only, static).

    Returns:
        `(B, nvp, 3)` vertex normals; zero rows on padded vertices and where the sum vanishes.
    """
    check_choice("weighting", weighting, _NORMAL_WEIGHTINGS)
    return _vertex_normals(require_batch("batch", batch), weighting=weighting, normalize=bool(normalize))


def _vertex_normals_one(faces: _Faces, vertices, *, weighting: str, normalize: bool):
    corners = faces.at_corners(vertices)
    area_vectors = _area_vectors(corners)
    if weighting == "area":
        corner_vectors = jnp.broadcast_to(area_vectors[:, None, :], corners.shape)
    else:
        unit = safe_normalize(area_vectors)
        if weighting == "angle":
            weights = unsigned_angle(jnp.roll(corners, -1, axis=1) - corners, jnp.roll(corners, -2, axis=1) - corners)
        else:
            weights = jnp.broadcast_to(faces.face_mask[:, None], corners.shape[:2]).astype(unit.dtype)
        corner_vectors = weights[:, :, None] * unit[:, None, :]
    sums = faces.to_vertices(corner_vectors)
    return safe_normalize(sums) if normalize else sums


@kernel(static_argnames=("weighting", "normalize"))
def _vertex_normals(batch: MeshBatch, *, weighting: str, normalize: bool) -> Float[Array, "B nvp 3"]:
    return _vmapped(lambda faces, vertices: _vertex_normals_one(faces, vertices, weighting=weighting, normalize=normalize))(batch)


def lumped_mass(batch: AnyBatch, *, mass: str = "voronoi") -> Float[Array, "B nvp"]:
    """The lumped mass matrix of each mesh as its diagonal, `(B, nvp)` (0 on padded vertices).

    `ddgjax.laplacian.mass_matrix(mesh, mass=mass).diagonal` per mesh, from the corner shares of
    `ddgjax.mesh.corner_dual_areas_from_lengths_sq`. libigl: `massmatrix(V, F, MASSMATRIX_TYPE_VORONOI).diagonal()`.

    Args:
        batch: `MeshBatch`.
        mass: one of `ddgjax.LUMPED_MASS_MATRICES`: `"voronoi"` (default; mixed Voronoi areas, Meyer et al. 2003)
            or `"barycentric"` (a third of each incident face) (keyword-only). `"galerkin"` is not diagonal and
            is refused: apply it with `mass_apply`.

    Returns:
        `(B, nvp)` vertex masses (dual areas), in the vertices' dtype; 0 on padded vertices.
    """
    check_mass(mass, LUMPED_MASS_MATRICES)
    return _lumped_mass(require_batch("batch", batch), mass=mass)


def _lumped_mass_one(faces: _Faces, vertices, *, mass: str):
    _, lengths_sq, areas, _ = faces.geometry(vertices)
    return faces.to_vertices(corner_dual_areas_from_lengths_sq(lengths_sq, dual=mass, areas=areas))


@kernel(static_argnames=("mass",))
def _lumped_mass(batch: MeshBatch, *, mass: str) -> Float[Array, "B nvp"]:
    return _vmapped(lambda faces, vertices: _lumped_mass_one(faces, vertices, mass=mass))(batch)


def mass_apply(batch: AnyBatch, u: Float[ArrayLike, "B nvp *k"], /, *, mass: str = "voronoi") -> Float[Array, "B nvp *k"]:
    """`M u` per mesh, `(B, nvp)` or `(B, nvp, k)`, for every `ddgjax.MASS_MATRICES` choice.

    Lumped masses multiply by `lumped_mass(batch, mass=mass)`; `"galerkin"` applies the consistent
    FEM mass matrix `M_ij = int phi_i phi_j` matrix-free: `(M u)_i = sum_{f ni i} A_f / 12 (u_i +
    sum_{k in f} u_k)` (`A_f/6` on the diagonal, `A_f/12` off it, as `ddgjax.laplacian.mass_matrix(
    mesh, mass="galerkin")`). Zero on padded vertices. libigl: `massmatrix(V, F, type) @ u`.

    Args:
        batch: `MeshBatch`.
        u: `(B, nvp)` or `(B, nvp, k)` padded vertex values (`pad_vertex_values`; positional-only).
        mass: one of `ddgjax.MASS_MATRICES`: `"voronoi"` (default), `"barycentric"` or `"galerkin"` (keyword-only).

    Returns:
        `M u` per mesh, the shape of `u`; 0 on padded vertices.
    """
    check_mass(mass)
    batch = require_batch("batch", batch)
    return _mass_apply(batch, _vertex_values(batch, u), mass=mass)


def _mass_apply_one(faces: _Faces, vertices, u, *, mass: str):
    if mass != "galerkin":
        masses = _lumped_mass_one(faces, vertices, mass=mass)
        return masses.reshape(masses.shape + (1,) * (u.ndim - 1)) * u
    _, _, areas, _ = faces.geometry(vertices)
    values = faces.at_corners(u)  # (nfp, 3, *k)
    twelfths = (areas / 12.0).reshape((-1, 1) + (1,) * (u.ndim - 1))
    return faces.to_vertices(twelfths * (values + jnp.sum(values, axis=1, keepdims=True)))


@kernel(static_argnames=("mass",))
def _mass_apply(batch: MeshBatch, u: Float[Array, "B nvp *k"], *, mass: str) -> Float[Array, "B nvp *k"]:
    return _vmapped(lambda faces, vertices, u: _mass_apply_one(faces, vertices, u, mass=mass))(batch, u)


def gradient(batch: AnyBatch, u: Float[ArrayLike, "B nvp"], /) -> Float[Array, "B nfp 3"]:
    """Per-face gradient of the piecewise-linear interpolant of `u`, `(B, nfp, 3)` (`ddgjax.dec.gradient` per mesh).

    `(grad u)_f = sum_k u[F[f, k]] grad phi_k`, `grad phi_k = (N x e_k) / (2 A)` (`ddgjax.mesh.face_hat_gradients`);
    zero on zero-area and padding faces. Reference: Crane et al., *The heat method* (2017), eq. (2).
    libigl: `igl.grad(V, F) @ u`; gpytoolbox: `grad(V, F) @ u`.

    Args:
        batch: `MeshBatch`.
        u: `(B, nvp)` padded vertex values (`pad_vertex_values`; one column; positional-only).

    Returns:
        `(B, nfp, 3)` gradient vectors, one per face; zero on zero-area and padded faces.
    """
    batch = require_batch("batch", batch)
    return _gradient(batch, _vertex_values(batch, u, columns=False))


def _gradient_one(faces: _Faces, vertices, u):
    corners = faces.at_corners(vertices)
    area_vectors = _area_vectors(corners)
    double_areas = 2.0 * safe_norm(area_vectors)
    normals = safe_div(area_vectors, double_areas[:, None] / 2.0)
    edge_vectors = jnp.roll(corners, -2, axis=1) - jnp.roll(corners, -1, axis=1)
    hat_gradients = safe_div(jnp.cross(normals[:, None, :], edge_vectors), double_areas[:, None, None])
    return jnp.einsum("fk,fkd->fd", faces.at_corners(u), hat_gradients)


@kernel
def _gradient(batch: MeshBatch, u: Float[Array, "B nvp"]) -> Float[Array, "B nfp 3"]:
    return jnp.where(batch.face_mask[..., None], _vmapped(_gradient_one)(batch, u), 0.0)
