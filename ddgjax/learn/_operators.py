"""What a diffusion network precomputes per shape: lumped mass, eigenbasis, tangent frames, spatial gradient.

`diffusion_operators(mesh, k)` returns DiffusionNet's per-shape operators (Sharp et al. 2022,
"DiffusionNet: Discretization Agnostic Learning on Surfaces", `get_operators`) as one pytree of
arrays, `DiffusionOperators`, differentiable in the vertex positions; `diffusion_operators_of_meshes`
does so for a dataset with a progress bar. With `cache_dir=` results are kept on disk by content (the
mesh's bytes and every setting), so a dataset's preprocessing runs once across training runs.
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import tempfile
from collections.abc import Iterable

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_choice, check_count, is_traced
from .._options import LUMPED_MASS_MATRICES, check_mass
from .._results import RESULTS, Solution, outcome
from ..discretization import discretize
from ..fields import TangentBases
from ..laplacian import IntrinsicTriangulation
from ..mesh import Mesh, require_mesh
from ..sparse import SparseMatrix
from ..spectral import smallest_eigenpairs
from ._gradient import gradient_frames_and_weights, neighbor_table

#: Changes whenever what a cache file holds or how it is computed changes; part of every file's name.
CACHE_FORMAT_VERSION = 1


class DiffusionOperators(eqx.Module):
    """Per-shape operators of a diffusion network; every leaf an array, so a list of them stacks into a batch.

    Shapes are those of one mesh; `stack_diffusion_operators` adds a leading batch axis (and padding).

    Attributes:
        mass: `(nv,)` the lumped mass `M` (vertex areas; 0 on padding).
        values: `(k,)` the smallest eigenvalues of `L phi = lambda M phi`, ascending.
        vectors: `(nv, k)` their M-orthonormal eigenvectors (`Phi^T M Phi = I`; rows of padding are 0).
        frames: `TangentBases(e1, e2, normal)`, each `(nv, 3)`: the frame of the tangent plane in which
            `spatial_gradients` are expressed (`e1` the first neighbour's edge made tangent).
        gradient_neighbors: `(nv, d)` integer: the one-ring of each vertex; free slots hold the vertex itself.
        gradient_weights: `(nv, d, 2)`: `grad u(i) = sum_j w_ij (u[n_ij] - u_i)` in `(e1, e2)` coordinates
            (0 on free slots).
    """

    mass: Float[Array, "*batch nv"]
    values: Float[Array, "*batch k"]
    vectors: Float[Array, "*batch nv k"]
    frames: TangentBases
    gradient_neighbors: Int[Array, "*batch nv d"]
    gradient_weights: Float[Array, "*batch nv d 2"]


def diffusion_operators(
    mesh: Mesh,
    k: int,
    *,
    mass: str = "voronoi",
    robust: bool | IntrinsicTriangulation = True,
    cache_dir: str | os.PathLike | None = None,
    throw: bool = True,
) -> DiffusionOperators | Solution:
    """`DiffusionOperators` of one mesh: lumped mass, `k` eigenpairs, tangent frames, spatial gradient weights.

    The eigenpairs are the `k` smallest of `L phi = lambda M phi` (`ddgjax.spectral.smallest_eigenpairs`),
    `L` the PSD cotan Laplacian and `M` the lumped mass; the gradient is the per-vertex least-squares
    fit of the one-ring (`ddgjax.learn._gradient`), in the frames of `operators.frames`.

    Args:
        mesh: the shape.
        k: the number of eigenpairs, `1 <= k < nv`.
        mass: `"voronoi"` (default) or `"barycentric"` (`ddgjax.LUMPED_MASS_MATRICES`); `"galerkin"`
            is refused: the spectral diffusion weighs by vertex areas. DiffusionNet's operators are
            `mass="barycentric"` (robust_laplacian's mass).
        robust: `True` (default): `L` and `M` of the mollified intrinsic Delaunay triangulation
            (Sharp & Crane 2020, `mollify_factor=1e-5`, as robust_laplacian and DiffusionNet), which
            works on meshes with degenerate faces and, through its tufted cover, on non-manifold and
            non-oriented meshes, as learning datasets have; `False`: the mesh's own
            cotan operators, refused (`MeshDataError`) on such meshes; or an `IntrinsicTriangulation`
            (`ddgjax.laplacian.intrinsic_delaunay(mesh)`, built outside `jit`): its operators at the
            given positions, the way to differentiate the robust operators in the vertex positions
            (`robust=True` flips edges on the host and needs concrete positions). The gradient and the
            frames use the mesh's own one-rings either way.
        cache_dir: a folder where the operators are kept, one `.npz` file per mesh and settings, named
            by the SHA-256 of the vertices' and faces' bytes and dtypes, `k`, `mass`, `robust` and
            `CACHE_FORMAT_VERSION`. A hit loads without computing; an unreadable file is recomputed and
            rewritten; files are written to a temporary name and renamed, so parallel readers never see
            half a file. Only concrete (untraced) meshes, `robust=True` / `False` and successful
            results are cached.
        throw: as `ddgjax.spectral.eigenpairs`: a failed eigensolve raises, or with `throw=False` the
            operators come in a `ddgjax.Solution` with `.result`.

    Returns:
        `DiffusionOperators`, differentiable in the vertex positions (eigenvectors away from repeated
        eigenvalues). Equivalent: DiffusionNet's `geometry.get_operators(verts, faces, k_eig)`
        (`frames, mass, L, evals, evecs, gradX, gradY`; its gradient is a sparse complex matrix, here a
        fixed-degree table).
    """
    mesh = require_mesh("mesh", mesh)
    mass = check_mass(mass, LUMPED_MASS_MATRICES)
    if not isinstance(robust, IntrinsicTriangulation):
        robust = check_choice("robust", robust, (True, False))
    nv = mesh.n_vertices
    k = check_count("k", k)
    if k >= nv:
        raise DDGInputError(f"k: expected fewer eigenpairs than the mesh's {nv} vertices, got {k}")
    path = None
    if cache_dir is not None and not is_traced(mesh.vertices) and not isinstance(robust, IntrinsicTriangulation):
        path = pathlib.Path(cache_dir) / f"{cache_key(mesh, k, mass=mass, robust=robust)}.npz"
        cached = _load(path)
        if cached is not None:
            return outcome(cached, RESULTS.successful, throw)
    operators, result, stats = _compute(mesh, k, mass=mass, robust=robust)
    # The item's index (equinox's `_value`) is read on the host rather than compared by a dispatched JAX op.
    if path is not None and bool(np.all(np.asarray(result._value) == RESULTS.successful._value)):
        _save(path, operators)
    return outcome(operators, result, throw, stats)


def _compute(mesh: Mesh, k: int, *, mass: str, robust: bool | IntrinsicTriangulation) -> tuple[DiffusionOperators, RESULTS, dict]:
    """The operators of `mesh` with the outcome and statistics of their eigensolve.

    The mesh's discretisation first (`ddgjax.discretization.discretize`: the degenerate-face check or the
    intrinsic flips, then `L` and `M`), the neighbour table, one compiled program for the frames and
    the gradient weights, then the eigensolve. Called eagerly, the eigensolve runs after the programs
    (ARPACK on the host, outside every program: `smallest_eigenpairs`), so each program can be kept
    across processes (`ddgjax._program_store`); under a transformation everything is traced inline.
    """
    discretization = discretize(mesh, mass=mass, robust=robust)
    L, M = discretization.laplacian, discretization.mass
    neighbors = device_array(neighbor_table(mesh.topology))
    areas, frames, weights = _geometry(mesh, M, neighbors)
    solution = smallest_eigenpairs(L, M, k, throw=False)
    values, vectors = solution.value
    operators = DiffusionOperators(
        mass=areas,
        values=values,
        vectors=vectors,
        frames=frames,
        gradient_neighbors=neighbors,
        gradient_weights=weights,
    )
    return operators, solution.result, solution.stats


@kernel
def _geometry(
    mesh: Mesh, M: SparseMatrix, neighbors: Int[Array, "nv d"]
) -> tuple[Float[Array, " nv"], TangentBases, Float[Array, "nv d 2"]]:
    """`(diag M, frames, gradient weights)`: with the discretisation's `L` and `M` and the eigenpairs, `DiffusionOperators`."""
    frames, weights = gradient_frames_and_weights(mesh, neighbors)
    return M.diagonal(), frames, weights


def cache_key(mesh: Mesh, k: int, *, mass: str, robust: bool) -> str:
    """The SHA-256 (hex) naming a mesh's cache file: its vertices' and faces' bytes, shapes and dtypes, and the settings."""
    digest = hashlib.sha256()
    for array in (np.asarray(mesh.vertices), np.asarray(mesh.faces)):
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype.str}{array.shape}".encode())
        digest.update(array.tobytes())
    digest.update(f"k={k};mass={mass};robust={robust};format={CACHE_FORMAT_VERSION}".encode())
    return digest.hexdigest()


_FIELDS = ("mass", "values", "vectors", "e1", "e2", "normal", "gradient_neighbors", "gradient_weights")


def _arrays(operators: DiffusionOperators) -> dict[str, Array]:
    frames = operators.frames
    return {
        "mass": operators.mass,
        "values": operators.values,
        "vectors": operators.vectors,
        "e1": frames.e1,
        "e2": frames.e2,
        "normal": frames.normal,
        "gradient_neighbors": operators.gradient_neighbors,
        "gradient_weights": operators.gradient_weights,
    }


def _load(path: pathlib.Path) -> DiffusionOperators | None:
    """The operators stored at `path`, or `None` when it is missing or unreadable (then they are recomputed)."""
    try:
        with np.load(path, allow_pickle=False) as stored:
            a = {name: jnp.asarray(stored[name]) for name in _FIELDS}
        return DiffusionOperators(
            mass=a["mass"],
            values=a["values"],
            vectors=a["vectors"],
            frames=TangentBases(a["e1"], a["e2"], a["normal"]),
            gradient_neighbors=a["gradient_neighbors"],
            gradient_weights=a["gradient_weights"],
        )
    except Exception:  # a truncated, corrupt or foreign file is a miss, not an error
        return None


def _save(path: pathlib.Path, operators: DiffusionOperators) -> None:
    """Write `operators` to `path` atomically: a temporary file in the same folder, then a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=path.stem, suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as file:
            np.savez(file, **{name: np.asarray(value) for name, value in _arrays(operators).items()})
        os.replace(temporary, path)
    except BaseException:
        pathlib.Path(temporary).unlink(missing_ok=True)
        raise


def diffusion_operators_of_meshes(
    meshes: Iterable[Mesh],
    k: int,
    *,
    mass: str = "voronoi",
    robust: bool = True,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = False,
    throw: bool = True,
) -> list[DiffusionOperators | Solution]:
    """`diffusion_operators` of every mesh of a dataset, with a `tqdm` progress bar if `progress=True`.

    A folder of files: `diffusion_operators_of_meshes(map(ddgjax.io.load_mesh, sorted(folder.glob("*.obj"))), k,
    cache_dir=folder / "operators")`. A host loop; batch the results with `stack_diffusion_operators`.
    """
    if progress:  # imported only when asked for: tqdm.auto warns in a Jupyter kernel without ipywidgets
        from tqdm.auto import tqdm

        meshes = tqdm(meshes, desc="diffusion operators")
    return [diffusion_operators(mesh, k, mass=mass, robust=robust, cache_dir=cache_dir, throw=throw) for mesh in meshes]
