"""What the mesh commands share: reading the MESH argument and writing the figure."""

from __future__ import annotations

import argparse
import math
import os
import sys

import jax.numpy as jnp

from .._errors import DDGInputError, MeshDataError
from ..io import load_mesh
from ..mesh import Mesh


def load_cli_mesh(path: str) -> tuple[str, Mesh]:
    """`(file name, mesh)` of the MESH argument in float64; `DDGInputError` / `MeshDataError` naming the file."""
    if not os.path.isfile(path):
        raise DDGInputError(f"MESH: expected an existing mesh file, got {path!r}")
    try:
        return os.path.basename(path), load_mesh(path, dtype=jnp.float64)
    except (DDGInputError, MeshDataError) as error:
        raise type(error)(f"{path}: {error}") from error


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
