"""What the mesh commands share: reading the MESH argument (a triangle or a tet mesh file) and writing the figure."""

from __future__ import annotations

import argparse
import math
import os
import pathlib
import sys

import jax.numpy as jnp

from .._errors import DDGInputError, MeshDataError
from ..io import load_mesh
from ..mesh import Mesh
from ..volume import TetMesh, load_tet_mesh

#: Triangle mesh files (`ddgjax.load_mesh`); a command that takes solids reads any other file as a tet mesh.
SURFACE_SUFFIXES = (".obj", ".off", ".ply", ".stl")


def is_tet_file(path: str) -> bool:
    """Whether `path` is read as a tet mesh (`ddgjax.volume.load_tet_mesh`): its suffix is not one of `SURFACE_SUFFIXES`.

    Every other suffix goes to the tet reader, so an unknown one is reported with the tet formats and
    the triangle ones (`load_cli_mesh`).
    """
    return pathlib.Path(path).suffix.lower() not in SURFACE_SUFFIXES


def load_cli_mesh(path: str, *, solids: bool = False) -> tuple[str, Mesh | TetMesh]:
    """`(file name, mesh)` of the MESH argument in float64; `DDGInputError` / `MeshDataError` naming the file.

    With `solids=True` a tet mesh file (`is_tet_file`) gives a `ddgjax.volume.TetMesh`; otherwise
    every file is read as a triangle mesh.
    """
    if not os.path.isfile(path):
        raise DDGInputError(f"MESH: expected an existing mesh file, got {path!r}")
    solid = solids and is_tet_file(path)
    try:
        return os.path.basename(path), (load_tet_mesh if solid else load_mesh)(path, dtype=jnp.float64)
    except (DDGInputError, MeshDataError) as error:
        read_as = f" (read as a tet mesh: triangle meshes are {', '.join(SURFACE_SUFFIXES)} files)" if solid else ""
        raise type(error)(f"{path}: {error}{read_as}") from error


def add_output_argument(parser, command: str, what: str = "figure file") -> None:
    """`--output` / `-o`, default `ddgjax_COMMAND.png`: every command names its figure one way."""
    default = f"ddgjax_{command}.png"
    parser.add_argument("--output", "-o", default=default, help=f"{what} (default {default})")


def write_figure(figure, output: str, command: str) -> bool:
    """Save `figure` to `output` and say so; on failure print `ddgjax COMMAND: error: ...` and return False."""
    try:
        figure.savefig(output, dpi=110)
    except OSError as error:
        print(f"ddgjax {command}: error: --output: could not write {output!r}: {error}", file=sys.stderr)
        return False
    print(f"figure written to {output}")
    return True


def positive(kind):
    """argparse type: a finite number of type `kind` (int or float) > 0."""

    def parse(text: str):
        value = kind(text)
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
        return value

    return parse
