"""Filling a closed triangle mesh with tetrahedra, through fTetWild (the optional `tetmesh` extra).

The mesher is fTetWild (Hu, Schneider, Wang, Zorin, Panozzo, "Fast Tetrahedral Meshing in the Wild",
SIGGRAPH 2020) through its Python bindings `pytetwild` (MPL-2.0, like fTetWild: file-level copyleft,
which an MIT library may depend on; wheels for Linux, macOS and Windows). The alternatives were
weighed and left: the `tetgen` bindings are MIT but bundle TetGen, which is AGPL-3.0, and gmsh is
GPL-2.0+. fTetWild is also the robust one: it accepts self-intersecting, non-manifold or slightly
open input and meshes its inside (winding-number filter), with well-shaped tets.
"""

from __future__ import annotations

import contextlib
import tempfile
import threading

import numpy as np

from .._errors import DDGInputError, check_positive
from ..mesh import Mesh, require_mesh
from ._tet_mesh import TetMesh

_WORKING_DIRECTORY_LOCK = threading.Lock()
_INSTALL = "pip install 'ddgjax[tetmesh]' (fTetWild's bindings pytetwild, MPL-2.0)"


def tetrahedralize(mesh: Mesh, *, edge_length=None, epsilon=1e-3) -> TetMesh:
    """Tetrahedral mesh of the solid a closed triangle mesh bounds (fTetWild; needs the `tetmesh` extra).

    fTetWild meshes the inside of the surface within an envelope: every boundary triangle of the
    result lies within `epsilon * d` of the input surface (`d` the diagonal of its bounding box), so
    the boundary is close to the surface but does not reuse its vertices (the number of vertices and
    tets is fTetWild's choice). Its tets are well shaped (it optimises their conformal AMIPS energy).
    The output differs slightly from run to run (fTetWild is not deterministic); tets are oriented by
    `TetMesh.from_arrays` and the vertices keep `mesh.vertices`' dtype.

    Args:
        mesh: a closed triangle `Mesh` (no boundary loops); self-intersections and non-manifold
            edges are tolerated by fTetWild.
        edge_length: the target tet edge length in the mesh's units; default `d / 20`.
        epsilon: the envelope's half-width relative to `d` (default `1e-3`, fTetWild's).

    Returns:
        A positively oriented `TetMesh` of the solid, its vertices in `mesh.vertices`' dtype.

    Raises `DDGInputError` for an open mesh, bad options, or when `pytetwild` is not installed
    (saying which extra to install). Equivalents: `pytetwild.tetrahedralize(V, F)`, the
    `FloatTetwild_bin` command line; `igl.copyleft.tetgen` / `tetgen.TetGen(V, F).tetrahedralize()`
    (TetGen, AGPL-3.0; keeps the surface's vertices).
    """
    mesh = require_mesh("mesh", mesh)
    loops = mesh.topology.boundary_loops
    if loops:
        raise DDGInputError(
            f"mesh: expected a closed surface (the boundary of a solid), got one with {len(loops)} boundary loops; "
            "close its holes first (ddgjax.mesh.check_mesh(mesh) lists them)"
        )
    if edge_length is not None:
        edge_length = check_positive("edge_length", edge_length)
    epsilon = check_positive("epsilon", epsilon)
    try:
        import pytetwild
    except ImportError as error:
        # pytetwild 0.3 and later import pyvista on import without declaring it (pyvista/pytetwild#38).
        extra = "; pytetwild >= 0.3 also needs pyvista (pip install pyvista)" if getattr(error, "name", "") == "pyvista" else ""
        raise DDGInputError(f"mesh: tetrahedralize needs fTetWild: {_INSTALL}{extra}") from error
    # fTetWild writes a scratch file (`__tracked_surface.stl`) into the working directory: run it in a
    # temporary one, under a lock because the working directory belongs to the whole process.
    with _WORKING_DIRECTORY_LOCK, tempfile.TemporaryDirectory() as scratch, contextlib.chdir(scratch):
        vertices, tets = pytetwild.tetrahedralize(
            np.array(mesh.vertices, dtype=np.float64, order="C"),
            np.array(mesh.faces, dtype=np.int32, order="C"),
            edge_length_abs=edge_length,
            epsilon=epsilon,
            quiet=True,
        )
    return TetMesh.from_arrays(np.asarray(vertices, dtype=mesh.vertices.dtype), np.asarray(tets, dtype=np.int64))
