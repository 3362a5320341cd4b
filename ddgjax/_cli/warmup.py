"""`ddgjax warmup MESH...`: compile the common entry points' programs for a set of meshes into the caches, once.

ddgjax's compiled programs are kept per argument signature, that is per mesh size (vertex and face
counts, `ddgjax._program_store`): a lab machine, a CI image or a dataset's first epoch can pay the
compilation for the sizes it will meet ahead of time, so that every later process (a notebook, a
training run) reads the programs from disk instead. MESH is a mesh file or a folder of them (every
`.obj`, `.off`, `.ply`, `.stl` inside, not recursing); each distinct size is warmed once.

The entry points warmed (`ENTRY_POINTS`): the cotan Laplacian and mass matrix, the curvatures of
`ddgjax info`, `solve_poisson`, `heat_distance`, `eigenpairs(k)` and, on oriented meshes, `log_map`.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
from tqdm import tqdm

from .._errors import DDGInputError, MeshDataError
from .._program_store import programs_directory, switched_on
from ..mesh import Mesh
from ._common import SURFACE_SUFFIXES, load_cli_mesh, positive


def _poisson(mesh: Mesh, k: int):
    from ..pde import solve_poisson

    rho = mesh.vertices[:, 2] - jnp.mean(mesh.vertices[:, 2])
    return solve_poisson(mesh, rho, fixed_vertices=[0], fixed_values=[0.0])


def _heat(mesh: Mesh, k: int):
    from ..geodesics import heat_distance

    return heat_distance(mesh, [0])


def _eigenpairs(mesh: Mesh, k: int):
    from ..spectral import eigenpairs

    return eigenpairs(mesh, min(k, mesh.n_vertices - 1))


def _log_map(mesh: Mesh, k: int):
    from ..geodesics import log_map

    return log_map(mesh, 0) if mesh.topology.is_oriented else None


def _operators(mesh: Mesh, k: int):
    from ..laplacian import laplacian_and_mass
    from ..mesh import vertex_angle_defects, vertex_mean_curvatures

    L, M = laplacian_and_mass(mesh)
    return L.values, M.values, vertex_angle_defects(mesh), vertex_mean_curvatures(mesh) if mesh.topology.is_oriented else None


#: name: function of `(mesh, k)`, in the order they run.
ENTRY_POINTS: dict[str, Callable] = {
    "laplacian": _operators,
    "poisson": _poisson,
    "heat": _heat,
    "eigenpairs": _eigenpairs,
    "log_map": _log_map,
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `ddgjax warmup`; its action is `run_warmup`."""
    parser.add_argument("mesh", nargs="+", help="mesh files or folders of them (.obj, .off, .ply, .stl)")
    parser.add_argument("-k", type=positive(int), default=20, help="eigenpair count to warm (default 20)")
    parser.add_argument(
        "--only",
        default=",".join(ENTRY_POINTS),
        help=f"comma-separated entry points to warm (default all: {','.join(ENTRY_POINTS)})",
    )
    parser.set_defaults(run=run_warmup)


def _mesh_files(arguments: list[str]) -> list[pathlib.Path]:
    files = []
    for argument in arguments:
        path = pathlib.Path(argument)
        if path.is_dir():
            files += sorted(p for p in path.iterdir() if p.suffix.lower() in SURFACE_SUFFIXES)
        elif path.is_file():
            files.append(path)
        else:
            raise DDGInputError(f"MESH: expected a mesh file or a folder of them, got {argument!r}")
    if not files:
        raise DDGInputError(f"MESH: no mesh files ({', '.join(SURFACE_SUFFIXES)}) in {' '.join(arguments)}")
    return files


def run_warmup(args: argparse.Namespace) -> int:
    """Action of `ddgjax warmup`: every chosen entry point once per distinct mesh size; 2 on bad input."""
    chosen = [name.strip() for name in args.only.split(",") if name.strip()]
    unknown = [name for name in chosen if name not in ENTRY_POINTS]
    try:
        if unknown:
            raise DDGInputError(f"--only: unknown entry points {unknown}; choose from {', '.join(ENTRY_POINTS)}")
        files = _mesh_files(args.mesh)
    except DDGInputError as error:
        print(f"ddgjax warmup: error: {error}", file=sys.stderr)
        return 2
    if not switched_on():
        print("ddgjax warmup: note: the program store is off (DDGJAX_COMPILATION_CACHE=0): nothing is kept", file=sys.stderr)
    seen, failed = set(), []
    start = time.perf_counter()
    for path in tqdm(files, desc="ddgjax warmup", unit="mesh"):
        try:
            _, mesh = load_cli_mesh(str(path))
        except (DDGInputError, MeshDataError) as error:
            failed.append(f"{path.name}: {error}")
            continue
        size = (mesh.n_vertices, mesh.n_faces, mesh.topology.is_oriented)
        if size in seen:
            continue
        seen.add(size)
        for name in chosen:
            try:
                jax.block_until_ready(ENTRY_POINTS[name](mesh, args.k))
            except (DDGInputError, MeshDataError) as error:  # a mesh one entry point refuses still warms the rest
                failed.append(f"{path.name}: {name}: {type(error).__name__}: {error}")
    print(f"warmed {len(chosen)} entry points for {len(seen)} mesh sizes in {time.perf_counter() - start:.1f} s")
    print(f"programs kept in {programs_directory()}")
    for line in failed:
        print(f"  skipped {line}", file=sys.stderr)
    return 0
