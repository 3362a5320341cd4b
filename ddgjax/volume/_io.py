"""Reading and writing tetrahedral meshes through meshio (gmsh .msh, VTK .vtk / .vtu, medit .mesh / .meshb, TetGen .ele / .node).

`load_tet_mesh` keeps the file's points in file order (points no tet
uses included, so per-vertex data lines up index for index, as `ddgjax.load_mesh` does) and takes
every block of linear tetrahedra (`tetra` cells), ignoring the file's other cells (a gmsh file's
boundary triangles, lines and points); a file whose tets are all negatively oriented is turned right
side out, any other keeps its tets as written (an inverted tet stays inverted, for `check_tet_mesh` and the
problem layer to report). `save_tet_mesh` writes the vertices and tets as given, in float64 (binary where the
format has it), so a round trip gives the same arrays back exactly, and replaces the target atomically as
`ddgjax.save_mesh` does (written aside, flushed, renamed into place); TetGen's two files (`.node`
positions, `.ele` tets) are replaced together (both or neither) and carry one tag, so `load_tet_mesh`
refuses a pair that was not written together.

meshio (MIT, pure Python; Schlömer et al., https://github.com/nschloe/meshio) is imported on first
use; libigl's equivalents are `igl.read_mesh` / `igl.write_mesh` (medit only) and
`igl.readMSH` (gmsh).
"""

from __future__ import annotations

import contextlib
import os
import pathlib
import tempfile
import uuid

import numpy as np

from .._errors import DDGInputError
from .._files import finite_host_vertices, replace_together
from ._tet_mesh import TetMesh, host_signed_volumes, require_tet_mesh, tet_mesh_as_given

#: The first line of both files of a TetGen pair `save_tet_mesh` writes (a comment to TetGen and meshio),
#: with one random token per save: `load_tet_mesh` refuses a pair whose tokens differ.
_PAIR_TAG = "# ddgjax tet pair"

#: File extension -> meshio's format (and the name of its reader / writer module, `meshio.gmsh`, ...).
_FORMATS = {
    ".msh": "gmsh",
    ".vtk": "vtk",
    ".vtu": "vtu",
    ".mesh": "medit",
    ".meshb": "medit",
    ".ele": "tetgen",
    ".node": "tetgen",
}


def load_tet_mesh(path: str | os.PathLike, *, dtype=None) -> TetMesh:
    """Read a tetrahedral mesh from a gmsh, VTK, medit or TetGen file (format from the extension).

    Args:
        path: a `.msh` (gmsh 2.2 / 4.x), `.vtk`, `.vtu`, `.mesh` / `.meshb` (medit) file, or for
            TetGen either the `.node` or the `.ele` file (the other must sit beside it).
        dtype: float dtype of `tet_mesh.vertices`; default: JAX's default float (float64 when x64 is
            enabled, as geometry wants; DESIGN.md).

    Returns:
        A `TetMesh` with the file's points in file order (unused ones kept, reported by
        `check_tet_mesh`) and the tets of every `tetra` block, in file order.

    Raises:
        FileNotFoundError: no such file.
        DDGInputError: another extension, content meshio cannot read, points that are
            not 3-D, or a file with no linear tetrahedra (naming the cell types it has: a triangle
            mesh goes to `ddgjax.load_mesh`, quadratic `tetra10` cells are not read), or a TetGen
            pair whose `.node` and `.ele` were not saved together by `save_tet_mesh`.

    Equivalents: `meshio.read(path)`; `igl.read_mesh(path)` for medit files.
    """
    import meshio  # first use only: a slow import

    path = pathlib.Path(path)
    fmt = _format_of(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no such tet mesh file: {str(path)!r}")
    if fmt == "tetgen":
        _check_pair(path)
    try:
        # The format's own reader: meshio.read prints and exits the process (SystemExit) on a file it cannot read.
        data = getattr(meshio, fmt).read(str(path))
    except meshio.ReadError as error:
        raise DDGInputError(f"path: meshio cannot read {str(path)!r} as {fmt}{': ' if str(error) else ''}{error}") from error
    except (ValueError, IndexError, KeyError, UnicodeDecodeError) as error:  # what meshio's parsers raise on broken content
        raise DDGInputError(f"path: {str(path)!r} is not a readable mesh file ({type(error).__name__}: {error})") from error
    blocks = [np.asarray(block.data) for block in data.cells if block.type == "tetra"]
    if not blocks:
        found = ", ".join(f"{block.type} x {len(block.data)}" for block in data.cells) or "no cells"
        hint = (
            " (a triangle mesh: ddgjax.load_mesh reads .obj, .off, .ply, .stl)"
            if any(b.type == "triangle" for b in data.cells)
            else ""
        )
        raise DDGInputError(
            f"path: {str(path)!r} contains no tetrahedra (cells found: {found}; {len(data.points)} points); "
            f"expected a tetrahedral mesh with 'tetra' cells{hint}"
        )
    points = np.asarray(data.points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise DDGInputError(f"path: {str(path)!r} has points of shape {points.shape}; expected 3-D points (n, 3)")
    points, tets = points.astype(np.float64), np.concatenate(blocks).astype(np.int64)
    # A file of the opposite convention (every tet negative) is turned right side out; a file with some tets
    # inverted keeps them so, for check_tet_mesh and the problem layer to see.
    tet_mesh = TetMesh.from_arrays(points, tets) if _every_tet_negative(points, tets) else tet_mesh_as_given(points, tets)
    return tet_mesh if dtype is None else tet_mesh.with_vertices(tet_mesh.vertices.astype(dtype))


def save_tet_mesh(path: str | os.PathLike, tet_mesh: TetMesh) -> None:
    """Write `tet_mesh` to a gmsh 4.1 `.msh`, `.vtk`, `.vtu`, medit `.mesh` / `.meshb` or TetGen `.ele` / `.node` file.

    Writes every vertex (unused ones too) in float64 and the tets as `tet_mesh.tets` holds them
    (inverted ones too), so `load_tet_mesh` gives back the same arrays exactly. The target is
    replaced atomically (`ddgjax.save_mesh`'s guarantee: a failed write leaves an existing file as
    it was); for TetGen both `stem.node` and `stem.ele` are written, whichever of the two `path` names,
    and replaced together: a failure leaves both old files, never a new `.node` beside an old `.ele`.

    Args:
        path: the target file, its extension the format (`.msh`, `.vtk`, `.vtu`, `.mesh`, `.meshb`, `.node`, `.ele`).
        tet_mesh: the tet mesh to write.

    Returns:
        None; the file (for TetGen, the `.node` and `.ele` pair) is written.

    Raises `DDGInputError`, before anything is written, for another extension, anything but a
    `TetMesh`, or vertices with NaN or inf coordinates; `OSError` when a file cannot be written.
    Equivalents: `meshio.write(path, meshio.Mesh(V, [("tetra", T)]))`; `igl.write_mesh` (medit).
    """
    tet_mesh = require_tet_mesh("tet_mesh", tet_mesh)
    path = pathlib.Path(path)
    fmt = _format_of(path)
    vertices = finite_host_vertices("tet_mesh", tet_mesh.vertices, path)
    import meshio

    data = meshio.Mesh(vertices, [("tetra", np.asarray(tet_mesh.tets, dtype=np.int64))])
    target = pathlib.Path(os.path.realpath(path))
    names = [target.with_suffix(".node").name, target.with_suffix(".ele").name] if fmt == "tetgen" else [target.name]
    # meshio writes only to paths (not to open files): it writes into a scratch folder of the system's (where
    # a killed process leaves nothing beside the user's files), and the files are then replaced together.
    with tempfile.TemporaryDirectory(prefix="ddgjax-") as scratch:
        meshio.write(pathlib.Path(scratch) / target.name, data, file_format=fmt)
        written = {name: (pathlib.Path(scratch) / name).read_bytes() for name in names}
    if fmt == "tetgen":
        tag = f"{_PAIR_TAG} {uuid.uuid4().hex}\n".encode()
        written = {name: tag + content for name, content in written.items()}
    replace_together(
        {target.with_name(name): lambda handle, content=content: handle.write(content) for name, content in written.items()}
    )


def _check_pair(path: pathlib.Path) -> None:
    """Refuse a TetGen `.node` / `.ele` pair whose files were not written together: both carry the tag
    `save_tet_mesh` writes as their first line, and the tags differ (one file was replaced without the other)."""
    tags = {}
    for suffix in (".node", ".ele"):
        with contextlib.suppress(OSError), open(path.with_suffix(suffix), encoding="utf-8", errors="replace") as handle:
            first = handle.readline()
            if first.startswith(_PAIR_TAG):
                tags[suffix] = first.split()[-1]
    if len(tags) == 2 and tags[".node"] != tags[".ele"]:
        raise DDGInputError(
            f"path: {str(path.with_suffix('.node'))!r} and {str(path.with_suffix('.ele'))!r} were not written together "
            f"(their save_tet_mesh tags differ: {tags['.node']} vs {tags['.ele']}), so the tets may index other vertices; "
            "save the tet mesh again, or restore the matching pair"
        )


def _every_tet_negative(points: np.ndarray, tets: np.ndarray) -> bool:
    if tets.size == 0 or tets.min() < 0 or tets.max() >= len(points):
        return False  # TetMesh's own checks name the problem
    volumes = host_signed_volumes(points, tets)
    return bool((volumes < 0).any() and not (volumes > 0).any())


def _format_of(path: pathlib.Path) -> str:
    fmt = _FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise DDGInputError(
            f"path: unknown tet mesh format {path.suffix!r} of {str(path)!r}; expected one of {', '.join(_FORMATS)}"
        )
    return fmt
