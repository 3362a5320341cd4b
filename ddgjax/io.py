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
round trip is exact, and binary float32 STL through trimesh; it refuses non-finite vertices before
writing anything and replaces the file atomically (a temporary file renamed into place), so a failed
write never damages an existing file.
"""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
import os
import pathlib
import tempfile
from collections.abc import Callable

import numpy as np

from ._errors import DDGInputError
from ._files import finite_host_vertices, write_atomically
from .mesh import Mesh, require_mesh

# The public API; everything else here (the imports, the readers) is an implementation detail.
__all__ = ["load_mesh", "save_mesh"]

_FORMATS = ("obj", "off", "ply", "stl")


def load_mesh(path: str | os.PathLike, *, dtype=None) -> Mesh:
    """Read a triangle mesh from an OBJ, OFF, PLY or STL file (format from the extension), compressed or not.

    Args:
        path: file path; the extension (case-insensitive) selects the format. A file compressed with
            xz, gzip or bzip2 (`spot.obj.xz`, `bunny.ply.gz`, `mesh.off.bz2`) is read through the
            extension before its compression's.
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
    opener = _DECOMPRESSORS.get(path.suffix.lower())
    if opener is not None:
        _format_of(path.with_suffix(""))  # an unknown inner format is refused before anything is read
        if not path.is_file():
            raise FileNotFoundError(f"path: no such mesh file: {str(path)!r}")
        # Unpacked beside nothing the user sees: a temporary folder, under the inner name (the readers want a path).
        with tempfile.TemporaryDirectory(prefix="ddgjax-mesh-") as folder, opener(path, "rb") as packed:
            unpacked = pathlib.Path(folder) / path.with_suffix("").name
            try:
                unpacked.write_bytes(packed.read())
            except (OSError, EOFError, lzma.LZMAError) as error:
                raise DDGInputError(f"path: {str(path)!r} could not be decompressed ({error})") from None
            return load_mesh(unpacked, dtype=dtype)
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
    """Write `mesh` to an OBJ, OFF, PLY or STL file (format from the extension), atomically.

    OBJ and OFF keep every vertex (unreferenced ones too) with 17 significant digits and PLY is
    binary float64, so `load_mesh` gives back the same arrays exactly; STL is binary float32 and
    keeps only the triangles (see the module docstring).

    Nothing is lost: the file is written to a temporary file in the target's folder, flushed to
    disk, then renamed over the target (`os.replace`), so a write that fails midway (a full disk, a
    file size limit, an error while formatting, an interrupt) leaves an existing file byte for byte
    as it was, and no temporary file behind. A replaced file keeps its permission bits; a new one
    gets the usual ones (`0o666` less the umask). A symbolic link is followed: its target is replaced.

    Args:
        path: file path; the extension (case-insensitive) selects the format (the path first, as
            `igl.write_triangle_mesh(path, V, F)` and `numpy.save(file, array)` take it).
        mesh: the mesh to write.

    Returns:
        None; the file at `path` is written (replaced when it exists).

    Raises `DDGInputError`, before anything is written, for an unknown extension, anything but a
    `Mesh`, or vertices with NaN or inf coordinates (whatever made them: `Mesh.from_arrays` refuses
    them, but `eqx.tree_at`, a `with_vertices` under `jit` or a flow that blew up can carry them);
    `OSError` when the file cannot be written (the old file is then untouched).
    Equivalent: `igl.write_triangle_mesh(path, V, F)`.
    """
    mesh = require_mesh("mesh", mesh)
    path = pathlib.Path(path)
    fmt = _format_of(path)
    vertices = finite_host_vertices(
        "mesh",
        mesh.vertices,
        path,
        " (mesh.with_vertices(V) with finite V; a flow that produced them has diverged: check its result)",
    )
    faces = np.asarray(mesh.faces, dtype=np.int64)
    write_atomically(pathlib.Path(os.path.realpath(path)), lambda handle: _WRITERS[fmt](handle, vertices, faces))


def _write_obj(handle: io.BufferedIOBase, vertices: np.ndarray, faces: np.ndarray) -> None:
    vertex_lines = "".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in vertices.tolist())
    face_lines = "".join(f"f {a} {b} {c}\n" for a, b, c in (faces + 1).tolist())
    handle.write((vertex_lines + face_lines).encode("ascii"))


def _write_off(handle: io.BufferedIOBase, vertices: np.ndarray, faces: np.ndarray) -> None:
    vertex_lines = "".join(f"{x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in vertices.tolist())
    face_lines = "".join(f"3 {a} {b} {c}\n" for a, b, c in faces.tolist())
    handle.write(f"OFF\n{vertices.shape[0]} {faces.shape[0]} 0\n{vertex_lines}{face_lines}".encode("ascii"))


def _write_ply(handle: io.BufferedIOBase, vertices: np.ndarray, faces: np.ndarray) -> None:
    header = (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {vertices.shape[0]}\n"
        "property double x\nproperty double y\nproperty double z\n"
        f"element face {faces.shape[0]}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    records = np.empty(faces.shape[0], dtype=[("count", "u1"), ("corners", "<i4", (3,))])
    records["count"] = 3
    records["corners"] = faces
    handle.write(header.encode("ascii"))
    handle.write(vertices.astype("<f8").tobytes())
    handle.write(records.tobytes())


def _write_stl(handle: io.BufferedIOBase, vertices: np.ndarray, faces: np.ndarray) -> None:
    # trimesh is imported where it is used: importing it takes ~1.6 s, which `import ddgjax` should not pay.
    import trimesh

    handle.write(trimesh.Trimesh(vertices=vertices, faces=faces, process=False).export(file_type="stl"))


_WRITERS: dict[str, Callable[[io.BufferedIOBase, np.ndarray, np.ndarray], None]] = {
    "obj": _write_obj,
    "off": _write_off,
    "ply": _write_ply,
    "stl": _write_stl,
}


# Compressed files `load_mesh` reads, by their last extension.
_DECOMPRESSORS = {".xz": lzma.open, ".gz": gzip.open, ".bz2": bz2.open}


def _format_of(path: pathlib.Path) -> str:
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in _FORMATS:
        raise DDGInputError(f"path: unknown mesh format {path.suffix!r} of {str(path)!r}; expected one of .obj, .off, .ply, .stl")
    return fmt


def _read_obj(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray]:
    """Positions and fan-triangulated faces of an OBJ file, by position index only."""
    with open(path, encoding="utf-8", errors="replace") as handle:
        lines = handle.read().splitlines()
    vertex_fields = [line.split()[1:4] for line in lines if line.startswith("v ")]
    face_lines = [number for number, line in enumerate(lines, start=1) if line.startswith("f ")]
    face_fields = [lines[number - 1].split()[1:] for number in face_lines]
    short = [k for k, fields in enumerate(vertex_fields) if len(fields) < 3]
    if short:
        raise DDGInputError(f"path: {str(path)!r}: vertex {short[0] + 1} has fewer than three coordinates")
    try:
        vertices = np.array(vertex_fields, dtype=np.float64).reshape(len(vertex_fields), 3)
    except ValueError:
        raise DDGInputError(f"path: {str(path)!r} has unreadable vertex coordinates") from None
    if not face_fields:
        return vertices, np.zeros((0, 3), dtype=np.int64)
    counts = np.fromiter(map(len, face_fields), dtype=np.int64, count=len(face_fields))
    if counts.min() < 3:
        line = face_lines[int(np.argmin(counts))]
        raise DDGInputError(f"path: {str(path)!r} line {line}: a face needs at least three corners")
    try:
        # Corner tokens are `v`, `v/vt`, `v//vn` or `v/vt/vn`; only the position index `v` is used.
        corners = np.array([token.split("/", 1)[0] for fields in face_fields for token in fields], dtype=np.int64)
    except ValueError:
        raise DDGInputError(f"path: {str(path)!r} has an unreadable face index") from None
    # OBJ is 1-based; a negative index counts back from the vertices read so far.
    if np.any(corners < 0):
        is_vertex = np.fromiter((line.startswith("v ") for line in lines), dtype=bool, count=len(lines))
        vertices_before = np.cumsum(is_vertex)[np.asarray(face_lines) - 1]
        corners = np.where(corners > 0, corners - 1, np.repeat(vertices_before, counts) + corners)
    else:
        corners = corners - 1
    # Fan triangulation (0, k, k+1) of each polygon, vectorised over all faces.
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    n_triangles = counts - 2
    first = np.repeat(starts, n_triangles)
    k = np.arange(n_triangles.sum()) - np.repeat(np.cumsum(n_triangles) - n_triangles, n_triangles) + 1
    return vertices, np.stack([corners[first], corners[first + k], corners[first + k + 1]], axis=1)


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
