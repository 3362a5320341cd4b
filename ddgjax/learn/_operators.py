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
import warnings
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
#: 2: each file holds its own `cache_key` (`"key"`), compared on load.
CACHE_FORMAT_VERSION = 2


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
    r"""`DiffusionOperators` of one mesh: lumped mass, `k` eigenpairs, tangent frames, spatial gradient weights.

    The eigenpairs are the `k` smallest of $L\phi = \lambda M\phi$ (`ddgjax.spectral.smallest_eigenpairs`),
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
            by `cache_key`: the SHA-256 of the vertices' and faces' bytes, shapes and dtypes, `k`,
            `mass`, `robust` and `CACHE_FORMAT_VERSION`. Each file also holds that key, and a file is
            used only when its key, its arrays' shapes (`nv`, `k`, the mesh's one-ring table), their
            dtypes (the vertices') and finite values all match; anything else (an unreadable, corrupt,
            stale or foreign file) is recomputed and rewritten. Files are written to a temporary name
            and renamed, so parallel readers never see half a file. A folder that cannot be written
            (read-only, a regular file, an impossible path) costs the caching only: the operators are
            returned, with one `UserWarning` naming the folder and the reason. Only concrete
            (untraced) meshes, `robust=True` / `False` and successful results are cached.
        throw: as `ddgjax.spectral.eigenpairs`: a failed eigensolve raises, or with `throw=False` the
            operators come in a `ddgjax.Solution` with `.result`.

    Returns:
        `DiffusionOperators`, differentiable in the vertex positions (eigenvectors away from repeated
        eigenvalues). Equivalent: DiffusionNet's `geometry.get_operators(verts, faces, k_eig)`
        (`frames, mass, L, evals, evecs, gradX, gradY`; its gradient is a sparse complex matrix, here a
        fixed-degree table).

    Examples:
        >>> import ddgjax
        >>> operators = ddgjax.learn.diffusion_operators(ddgjax.mesh.icosphere(2), 16)
        >>> operators.mass.shape, operators.values.shape, operators.vectors.shape
        ((162,), (16,), (162, 16))
    """
    operators, unwritable = _cached_operators(mesh, k, mass=mass, robust=robust, cache_dir=cache_dir, throw=throw)
    if unwritable is not None:
        warnings.warn(unwritable, stacklevel=2)
    return operators


def _cached_operators(
    mesh: Mesh, k: int, *, mass: str, robust: bool | IntrinsicTriangulation, cache_dir, throw: bool
) -> tuple[DiffusionOperators | Solution, str | None]:
    """`diffusion_operators`' answer and, when its cache file could not be written, the warning to give."""
    mesh = require_mesh("mesh", mesh)
    mass = check_mass(mass, LUMPED_MASS_MATRICES)
    if not isinstance(robust, IntrinsicTriangulation):
        robust = check_choice("robust", robust, (True, False))
    nv = mesh.n_vertices
    k = check_count("k", k)
    if k >= nv:
        raise DDGInputError(f"k: expected fewer eigenpairs than the mesh's {nv} vertices, got {k}")
    path = key = None
    if cache_dir is not None and not is_traced(mesh.vertices) and not isinstance(robust, IntrinsicTriangulation):
        key = cache_key(mesh, k, mass=mass, robust=robust)
        path = pathlib.Path(cache_dir) / f"{key}.npz"
        cached = _matching(_load(path), mesh, k, key)
        if cached is not None:
            return outcome(cached, RESULTS.successful, throw), None
    operators, result, stats = _compute(mesh, k, mass=mass, robust=robust)
    unwritable = None
    # The item's index (equinox's `_value`) is read on the host rather than compared by a dispatched JAX op.
    if path is not None and bool(np.all(np.asarray(result._value) == RESULTS.successful._value)):
        try:
            _save(path, operators, key)
        except (OSError, ValueError) as error:  # ValueError: a path with a NUL byte
            unwritable = (
                f"cache_dir: cannot write the operators' cache file in {os.fsdecode(cache_dir)!r} "
                f"({_reason(error, path.parent)}); the operators are returned without being cached"
            )
    return outcome(operators, result, throw, stats), unwritable


def _reason(error: Exception, folder: pathlib.Path) -> str:
    """Why `folder` took no file, in words: the OS's message without the temporary file's name."""
    try:
        if folder.exists() and not folder.is_dir():
            return "it is a regular file, not a folder"
    except (OSError, ValueError):
        pass
    if isinstance(error, OSError) and error.strerror:
        return error.strerror
    return str(error)


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


def _load(path: pathlib.Path) -> tuple[str, dict[str, np.ndarray]] | None:
    """The key and arrays stored at `path`, or `None` when it is missing, unreadable or not a cache file."""
    try:
        # Opened here: `np.load` leaves its own handle open when the zip is truncated.
        with open(path, "rb") as file, np.load(file, allow_pickle=False) as stored:
            if sorted(stored.files) != sorted((*_FIELDS, "key")):
                return None
            key = stored["key"]
            if key.dtype.kind != "U" or key.shape != ():
                return None
            return str(key), {name: stored[name] for name in _FIELDS}
    except Exception:  # a truncated, corrupt or foreign file is a miss, not an error
        return None


def _matching(stored: tuple[str, dict[str, np.ndarray]] | None, mesh: Mesh, k: int, key: str) -> DiffusionOperators | None:
    """The stored operators if they are `mesh`'s for `k` under `key`, else `None` (then they are recomputed).

    The key (content and settings) is compared first; the shapes against `nv`, `k` and the mesh's
    one-ring table, the floats' dtype against the vertices' and their finiteness guard against a file
    written with the right key by something else.
    """
    if stored is None or stored[0] != key:
        return None
    a = stored[1]
    nv, dtype = mesh.n_vertices, np.dtype(mesh.vertices.dtype)
    neighbors = neighbor_table(mesh.topology)
    d = neighbors.shape[1]
    shapes = {
        "mass": (nv,),
        "values": (k,),
        "vectors": (nv, k),
        "e1": (nv, 3),
        "e2": (nv, 3),
        "normal": (nv, 3),
        "gradient_neighbors": (nv, d),
        "gradient_weights": (nv, d, 2),
    }
    for name, shape in shapes.items():
        if a[name].shape != shape:
            return None
        if name != "gradient_neighbors" and (a[name].dtype != dtype or not np.all(np.isfinite(a[name]))):
            return None
    if a["gradient_neighbors"].dtype.kind not in "iu" or not np.array_equal(a["gradient_neighbors"], neighbors):
        return None
    return DiffusionOperators(
        mass=jnp.asarray(a["mass"]),
        values=jnp.asarray(a["values"]),
        vectors=jnp.asarray(a["vectors"]),
        frames=TangentBases(jnp.asarray(a["e1"]), jnp.asarray(a["e2"]), jnp.asarray(a["normal"])),
        gradient_neighbors=device_array(neighbors),
        gradient_weights=jnp.asarray(a["gradient_weights"]),
    )


def _save(path: pathlib.Path, operators: DiffusionOperators, key: str) -> None:
    """Write `operators` and their `key` to `path` atomically: a temporary file in the same folder, then a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=path.stem, suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as file:
            arrays = {name: np.asarray(value) for name, value in _arrays(operators).items()}
            np.savez(file, key=np.asarray(key), **arrays)
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
    A `cache_dir` that cannot be written gives one warning for the whole dataset.

    Args:
        meshes: the meshes, any iterable (consumed once, in order).
        k: the number of eigenpairs of each, `1 <= k < nv`.
        mass, robust, cache_dir, throw: as for `diffusion_operators` (keyword-only).
        progress: `True` for a `tqdm` progress bar (keyword-only; default `False`).

    Returns:
        A list with one `DiffusionOperators` per mesh, in order (a `ddgjax.Solution` each with `throw=False`).
    """
    if progress:  # imported only when asked for: tqdm.auto warns in a Jupyter kernel without ipywidgets
        from tqdm.auto import tqdm

        meshes = tqdm(meshes, desc="diffusion operators")
    results, unwritable = [], None
    for mesh in meshes:
        operators, failed = _cached_operators(mesh, k, mass=mass, robust=robust, cache_dir=cache_dir, throw=throw)
        results.append(operators)
        unwritable = unwritable or failed
    # One warning for the dataset, not one a mesh: a read-only folder refuses every file alike.
    if unwritable is not None:
        warnings.warn(unwritable, stacklevel=2)
    return results
