"""What a learning pipeline precomputes per shape: eigenbasis, mass and gradient operator, in one call.

Spectral and diffusion networks on meshes (e.g. DiffusionNet, Sharp et al. 2022) need, for every
training shape, the lumped mass `M`, the first eigenpairs of `L phi = lambda M phi` (spectral
diffusion `Phi exp(-lambda t) Phi^T M u`) and a gradient operator; `shape_operators(mesh, k)` returns
them as one pytree (`ShapeOperators`), and `shape_operators_of_meshes(meshes, k)` does so for a
dataset of meshes with a progress bar, the host loop a dataset's preprocessing runs once.

The gradient operator is the `(3 nf, nv)` matrix `G` with `G u` the per-face gradient of the
piecewise-linear `u`, flattened face by face (`(G u).reshape(nf, 3) == ddgjax.dec.gradient(mesh, u)`):
entries `grad phi_j` of each face's hat functions (Crane 2020, section 6.2).
"""

from __future__ import annotations

import weakref
from collections.abc import Iterable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._compile import device_array, kernel
from .._options import LUMPED_MASS_MATRICES, check_mass
from .._results import Solution, outcome
from ..laplacian import IntrinsicTriangulation, laplacian_and_mass
from ..mesh import Mesh, MeshTopology, face_hat_gradients, require_mesh
from ..sparse import SparseMatrix, SparsityPattern
from ._generalized import smallest_eigenpairs

"""The `mass=` values `shape_operators` takes: a learning pipeline applies `M^{-1}` pointwise, so `M` is lumped."""


class ShapeOperators(eqx.Module):
    """Per-shape operators for learning on meshes (module docstring).

    Attributes:
        mass: `(nv,)` the lumped mass (vertex areas) `M`.
        values: `(k,)` the smallest eigenvalues of `L phi = lambda M phi`.
        vectors: `(nv, k)` their M-orthonormal eigenvectors.
        laplacian: the `(nv, nv)` PSD cotan Laplacian `L`.
        gradient: the `(3 nf, nv)` gradient operator `G`.
    """

    mass: Float[Array, " nv"]
    values: Float[Array, " k"]
    vectors: Float[Array, "nv k"]
    laplacian: SparseMatrix
    gradient: SparseMatrix


def shape_operators(
    mesh: Mesh, k: int, *, mass: str = "voronoi", robust: bool | IntrinsicTriangulation = False, throw: bool = True
) -> ShapeOperators | Solution:
    """`ShapeOperators` of one mesh: the lumped mass, `k` eigenpairs of `L phi = lambda M phi`, `L`, `G`.

    `mass`: `"voronoi"` (default) or `"barycentric"`; `"galerkin"` is refused (`DDGInputError`): the
    operators are stored for pipelines that divide by the vertex areas, which a full mass matrix does
    not have. `robust`: the intrinsic Delaunay `L` and `M` (mollified: they work on meshes with
    degenerate faces, which `robust=False` refuses with `MeshDataError`;
    `ddgjax.laplacian.laplacian_and_mass`); `G` stays the mesh's own. `throw`: as
    `ddgjax.spectral.eigenpairs` (a failed eigensolve raises, or with `throw=False` the
    `ShapeOperators` come in a `ddgjax.Solution`). libigl / gpytoolbox: none in one call
    (DiffusionNet's `get_operators` computes the same set, with robust_laplacian's operators).
    """
    mesh = require_mesh("mesh", mesh)
    check_mass(mass, LUMPED_MASS_MATRICES)
    L, M = laplacian_and_mass(mesh, mass=mass, robust=robust)
    solution = smallest_eigenpairs(L, M, k, throw=False)
    values, vectors = solution.value
    operators = ShapeOperators(mass=M.diagonal(), values=values, vectors=vectors, laplacian=L, gradient=gradient_operator(mesh))
    return outcome(operators, solution.result, throw, solution.stats)


def gradient_operator(mesh: Mesh) -> SparseMatrix:
    """The `(3 nf, nv)` matrix `G` of the per-face gradient of vertex functions (module docstring)."""
    mesh = require_mesh("mesh", mesh)
    pattern, slot = _gradient_pattern(mesh.topology)
    return SparseMatrix(_gradient_values(mesh, slot, nnz=pattern.nnz), pattern)


# Keyed by topology, which compares by content: meshes of one connectivity share one pattern.
_GRADIENT_PATTERNS: "weakref.WeakKeyDictionary[MeshTopology, tuple[SparsityPattern, Array]]" = weakref.WeakKeyDictionary()


def _gradient_pattern(topology: MeshTopology) -> tuple[SparsityPattern, Int[Array, " m"]]:
    """`(pattern, slot)` of `G` for this connectivity: entry `(f, j, c)` of `face_hat_gradients` lands in `slot`."""
    cached = _GRADIENT_PATTERNS.get(topology)
    if cached is None:
        faces = np.asarray(topology.faces)
        nf = faces.shape[0]
        rows = (3 * np.arange(nf)[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)  # row 3 f + c
        cols = np.repeat(faces[:, :, None], 3, axis=2)  # column: the face's corner j
        # Host work even when called inside a caller's trace: the pattern depends on the topology only.
        with jax.ensure_compile_time_eval():
            pattern, slot = SparsityPattern.from_coo(rows.ravel(), cols.ravel(), (3 * nf, topology.n_vertices))
            cached = _GRADIENT_PATTERNS[topology] = (pattern, device_array(slot))
    return cached


@kernel(static_argnames=("nnz",))
def _gradient_values(mesh: Mesh, slot: Int[Array, " m"], *, nnz: int) -> Float[Array, " nnz"]:
    """The values of `G` on its pattern's `nnz` slots (one compiled program per mesh size)."""
    entries = face_hat_gradients(mesh)  # [f, j, c]
    return jnp.zeros(nnz, entries.dtype).at[slot].add(entries.ravel())


def shape_operators_of_meshes(
    meshes: Iterable[Mesh], k: int, *, mass: str = "voronoi", robust: bool = False, progress: bool = True, throw: bool = True
) -> list[ShapeOperators | Solution]:
    """`shape_operators` of every mesh of a dataset, with a `tqdm` progress bar (`progress=False` silences it).

    A folder of files: `shape_operators_of_meshes(map(ddgjax.io.load_mesh, sorted(folder.glob("*.obj"))), k)`.
    A host loop; each shape compiles once per connectivity size. Stack same-size results with
    `jax.tree.map(jnp.stack, *operators)` to batch them. With `throw=False` each entry is a
    `ddgjax.Solution` (`shape_operators`). `robust=True` builds every shape's intrinsic Delaunay
    operators (for datasets with degenerate faces, which `robust=False` refuses).
    """
    from tqdm.auto import tqdm

    return [
        shape_operators(mesh, k, mass=mass, robust=robust, throw=throw)
        for mesh in tqdm(meshes, disable=not progress, desc="shapes")
    ]
