"""Reading and writing triangle meshes (OBJ, OFF, PLY, STL).

`load_mesh` keeps the file's vertex order and its unreferenced vertices, so per-vertex data computed
elsewhere (libigl's `read_triangle_mesh`, a texture, a reference solution) lines up index for index:

- **OBJ** is parsed here, by position index: only `v` and `f` lines are read, `f a/b/c` corners use
  the position index `a` (1-based; negative indices count back from the last vertex read so far),
  and polygons are fan-triangulated `(0, k, k+1)`. trimesh is not used because it splits vertices
  at texture seams (Crane's spot would load with 3,225 vertices, 13 components and boundary instead
  of 2,930 vertices, closed) and drops unreferenced ones.
- **OFF** and **PLY** go through `trimesh.load(..., process=False, maintain_order=True)`, which keeps
  the order and the unreferenced vertices (polygons are triangulated by trimesh).
- **STL** stores each triangle's corners separately; identical corner positions are merged into one
  vertex (numbered in order of first appearance), as every STL reader that builds a mesh must.
  STL has float32 coordinates and no unreferenced vertices, so a round trip is exact only up to
  float32 rounding and a renumbering of the vertices.

`save_mesh` writes OBJ and OFF (17 significant digits) and binary float64 PLY itself, so a float64
round trip is exact, and binary float32 STL through trimesh.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from ._errors import DDGInputError
from .mesh._mesh import Mesh

_FORMATS = ("obj", "off", "ply", "stl")


def load_mesh(path: str | os.PathLike, *, dtype=None) -> Mesh:
    """Read a triangle mesh from an OBJ, OFF, PLY or STL file (format from the extension).

    Args:
        path: file path; the extension (case-insensitive) selects the format.
        dtype: float dtype of `mesh.vertices` (e.g. `jnp.float64`); default: JAX's default float
            (float64 when x64 is enabled, as geometry wants; DESIGN.md).

    Returns:
        A `Mesh` with the file's vertices in file order (unreferenced ones kept; see the module
        docstring for STL) and its polygons fan-triangulated.

    Raises:
        FileNotFoundError: no such file.
        DDGInputError: unknown extension, unreadable content, or a file with no faces (point clouds
            are not meshes) or out-of-range face indices.

    Equivalent: `igl.read_triangle_mesh(path)` (same vertex order for OBJ, OFF and PLY).
    """
    path = pathlib.Path(path)
    fmt = _format_of(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no such mesh file: {str(path)!r}")
    if fmt == "obj":
        vertices, faces = _read_obj(path)
    else:
        vertices, faces = _read_with_trimesh(path, fmt)
    if faces.shape[0] == 0:
        raise DDGInputError(f"path: {str(path)!r} contains no faces ({vertices.shape[0]} vertices); expected a triangle mesh")
    mesh = Mesh.from_arrays(vertices, faces)
    if dtype is not None:
        mesh = mesh.with_vertices(mesh.vertices.astype(dtype))
    return mesh


def save_mesh(path: str | os.PathLike, mesh: Mesh) -> None:
    """Write `mesh` to an OBJ, OFF, PLY or STL file (format from the extension).

    OBJ and OFF keep every vertex (unreferenced ones too) with 17 significant digits and PLY is
    binary float64, so `load_mesh` gives back the same arrays exactly; STL is binary float32 and
    keeps only the triangles (see the module docstring).
    """
    path = pathlib.Path(path)
    fmt = _format_of(path)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if fmt in ("obj", "off"):
        vertex_lines = "\n".join(" ".join(f"{x:.17g}" for x in row) for row in vertices.tolist())
        if fmt == "obj":
            face_lines = "\n".join(f"f {a} {b} {c}" for a, b, c in (faces + 1).tolist())
            text = "\n".join(f"v {line}" for line in vertex_lines.split("\n")) + "\n" + face_lines + "\n"
        else:
            face_lines = "\n".join(f"3 {a} {b} {c}" for a, b, c in faces.tolist())
            text = f"OFF\n{vertices.shape[0]} {faces.shape[0]} 0\n{vertex_lines}\n{face_lines}\n"
        path.write_text(text)
        return
    if fmt == "ply":
        header = (
            f"ply\nformat binary_little_endian 1.0\nelement vertex {vertices.shape[0]}\n"
            "property double x\nproperty double y\nproperty double z\n"
            f"element face {faces.shape[0]}\nproperty list uchar int vertex_indices\nend_header\n"
        )
        records = np.empty(faces.shape[0], dtype=[("count", "u1"), ("corners", "<i4", (3,))])
        records["count"] = 3
        records["corners"] = faces
        with open(path, "wb") as handle:
            handle.write(header.encode("ascii"))
            handle.write(vertices.astype("<f8").tobytes())
            handle.write(records.tobytes())
        return
    import trimesh

    trimesh.Trimesh(vertices=vertices, faces=faces, process=False).export(str(path), file_type=fmt)


def _format_of(path: pathlib.Path) -> str:
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in _FORMATS:
        raise DDGInputError(f"path: unknown mesh format {path.suffix!r} of {str(path)!r}; expected one of .obj, .off, .ply, .stl")
    return fmt


def _read_obj(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray]:
    """Positions and fan-triangulated faces of an OBJ file, by position index only."""
    coordinates: list[str] = []
    n_vertices = 0
    triangles: list[tuple[int, int, int]] = []
    with open(path, encoding="utf-8", errors="replace") as handle:
        for number, line in enumerate(handle, start=1):
            if line.startswith("v "):
                fields = line.split()
                if len(fields) < 4:
                    raise DDGInputError(f"path: {str(path)!r} line {number}: a vertex needs three coordinates, got {line.strip()!r}")
                coordinates.extend(fields[1:4])
                n_vertices += 1
            elif line.startswith("f "):
                try:
                    corners = [int(token.split("/", 1)[0]) for token in line.split()[1:]]
                except ValueError:
                    raise DDGInputError(f"path: {str(path)!r} line {number}: unreadable face {line.strip()!r}") from None
                if len(corners) < 3:
                    raise DDGInputError(f"path: {str(path)!r} line {number}: a face needs at least three corners, got {line.strip()!r}")
                # OBJ is 1-based; a negative index counts back from the vertices read so far.
                indices = [c - 1 if c > 0 else n_vertices + c for c in corners]
                triangles.extend((indices[0], indices[k], indices[k + 1]) for k in range(1, len(indices) - 1))
    try:
        vertices = np.array(coordinates, dtype=np.float64).reshape(n_vertices, 3)
    except ValueError:
        raise DDGInputError(f"path: {str(path)!r} has unreadable vertex coordinates") from None
    faces = np.array(triangles, dtype=np.int64).reshape(-1, 3)
    return vertices, faces


def _read_with_trimesh(path: pathlib.Path, fmt: str) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    try:
        loaded = trimesh.load(str(path), file_type=fmt, process=False, maintain_order=True, force="mesh")
    except Exception as error:  # trimesh raises many kinds; report the file and the cause uniformly
        raise DDGInputError(f"path: could not read {str(path)!r} as {fmt.upper()}: {error}") from error
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
    if fmt == "stl" and faces.size:
        vertices, faces = _merge_identical_vertices(vertices, faces)
    return vertices, faces


def _merge_identical_vertices(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge bit-identical positions, numbering the merged vertices by first appearance."""
    _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    rank = np.empty(first.size, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(first.size)
    return vertices[np.sort(first)], rank[inverse.reshape(-1)][faces]
