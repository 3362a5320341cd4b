"""What matching needs of each shape: the mesh, its lumped mass and the first eigenpairs of its Laplacian.

pyFM's `TriMesh` after `process(k)` holds the same. Functional maps are written in these bases: a
`(k_target, k_source)` matrix `C` takes the coefficients `a = Phi_s^T M_s f` of a function `f` on the
source to those of its image on the target, `C a` (Ovsjanikov et al. 2012, section 4).
"""

from __future__ import annotations

import equinox as eqx
import numpy as np
from jaxtyping import Array, Float

from .._errors import DDGInputError
from .._options import LUMPED_MASS_MATRICES, check_mass
from .._results import Solution, outcome
from ..laplacian import IntrinsicTriangulation, laplacian_and_mass
from ..mesh import Mesh, require_mesh
from ..spectral import smallest_eigenpairs


class SpectralShape(eqx.Module):
    """A mesh with its lumped mass and the `k` smallest eigenpairs of `L phi = lambda M phi` (a pytree).

    Attributes:
        mesh: the triangle mesh.
        mass: `(nv,)` the lumped mass (vertex areas) `M`.
        values: `(k,)` the eigenvalues, ascending (the first is 0 on a closed or Neumann mesh).
        vectors: `(nv, k)` the M-orthonormal eigenvectors `Phi` (`Phi^T M Phi = I`).
    """

    mesh: Mesh
    mass: Float[Array, " nv"]
    values: Float[Array, " k"]
    vectors: Float[Array, "nv k"]

    @property
    def k(self) -> int:
        """The number of eigenpairs."""
        return self.values.shape[0]


def spectral_shape(
    mesh: Mesh, k: int, *, mass: str = "voronoi", robust: bool | IntrinsicTriangulation = False, throw: bool = True
) -> SpectralShape | Solution:
    """`SpectralShape` of a mesh: its lumped mass and `k` eigenpairs (`ddgjax.spectral.eigenpairs`).

    Differentiable in the vertex positions (`ddgjax.spectral.smallest_eigenpairs`). pyFM:
    `TriMesh(V, F).process(k, intrinsic=robust)`.

    Args:
        mesh: the mesh.
        k: the number of eigenpairs, fewer than `nv`.
        mass: `"voronoi"` (default) or `"barycentric"` (keyword-only; lumped: point maps and descriptors
            weigh vertices by their areas).
        robust: `False` (default): the mesh's cotan operators; `True`: the intrinsic Delaunay Laplacian and
            mass (meshes with degenerate faces); or an `IntrinsicTriangulation` (keyword-only).
        throw: `True` (default): a failed eigensolve raises; `False`: the shape comes in a `ddgjax.Solution`
            (keyword-only).

    Returns:
        The `SpectralShape` (in a `ddgjax.Solution` with `throw=False`).
    """
    mesh = require_mesh("mesh", mesh)
    check_mass(mass, LUMPED_MASS_MATRICES)
    L, M = laplacian_and_mass(mesh, mass=mass, robust=robust)
    solution = smallest_eigenpairs(L, M, k, throw=False)
    values, vectors = solution.value
    shape = SpectralShape(mesh=mesh, mass=M.diagonal(), values=values, vectors=vectors)
    return outcome(shape, solution.result, throw, solution.stats)


def require_spectral_shape(name: str, value) -> SpectralShape:
    """`value` if it is a `SpectralShape`, else `DDGInputError` saying how to make one."""
    if not isinstance(value, SpectralShape):
        raise DDGInputError(
            f"{name}: expected a ddgjax.matching.SpectralShape (make one with spectral_shape(mesh, k)), "
            f"got {type(value).__name__}"
        )
    return value


def require_connected(name: str, mesh: Mesh, caller: str) -> None:
    """`DDGInputError` unless the mesh's referenced vertices form one component (joined by edges).

    A functional map fixes its first column as if `phi_0` were the constant function on both shapes;
    each further component adds a zero eigenvalue whose eigenvector is any mix of the components'
    indicators, which that column cannot place. Counted once per mesh on the host.
    """
    n_components = mesh.host_fact("vertex_components", lambda: _vertex_components(mesh))
    if n_components > 1:
        raise DDGInputError(
            f"{name}: {caller} matches connected surfaces, and this mesh has {n_components} connected "
            f"components: each adds a zero eigenvalue whose eigenvector the functional map cannot place (its "
            "first column maps the constant function alone). Match each component on its own: build its mesh "
            "with ddgjax.Mesh.from_arrays from the faces of one label of mesh.topology.face_components"
        )


def _vertex_components(mesh: Mesh) -> int:
    """The connected components of the mesh's referenced vertices, joined by edges: the multiplicity of `L`'s zero eigenvalue.

    Counted on the host topology (linear in the edges). Faces that share only a vertex are one
    component here (the Laplacian couples them through it), unlike `topology.n_components`.
    """
    topology = mesh.topology
    if topology is None:  # `Mesh.without_topology()` (what kernels trace): nothing on the host to count
        return 1
    # Imported on first use, as ddgjax.mesh does: scipy.sparse.csgraph is slow to import.
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    edges = np.asarray(topology.edges)
    n = topology.n_vertices
    graph = coo_matrix((np.ones(edges.shape[0], np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return int(np.unique(labels[np.asarray(topology.faces).ravel()]).size)
