"""`ddgjax info [MESH]`: topology report, area, volume, Gauss-Bonnet check and curvature statistics.

A tetrahedral mesh file (gmsh `.msh`, `.vtk`, `.vtu`, medit `.mesh` / `.meshb`, TetGen `.ele` /
`.node`: `ddgjax.volume.load_tet_mesh`) gets the tet report instead: `check_tet_mesh`, the volume, the
boundary surface's area and enclosed volume, and the spread of tet volumes and dihedral angles.

With `--output FILE` it also draws the pointwise Gaussian curvature and, on an oriented mesh, the mean
curvature on the mesh (`ddgjax.plot.plot_mesh_function`, diverging colours centred on 0).
"""

from __future__ import annotations

import argparse
import sys

import jax
import jax.numpy as jnp
import numpy as np

from .._compile import kernel
from .._errors import DDGInputError, MeshDataError
from ..io import load_mesh
from ..mesh import (
    Mesh,
    MeshReport,
    check_mesh,
    enclosed_volume,
    torus,
    total_area,
    vertex_angle_defects,
    vertex_pointwise_gaussian_curvatures,
    vertex_pointwise_mean_curvatures,
    vertex_principal_curvatures,
)
from ..volume import (
    TetMesh,
    TetMeshReport,
    check_tet_mesh,
    load_tet_mesh,
    tet_dihedral_angles,
    tet_signed_volumes,
)
from ._common import is_tet_file, write_figure

_DEFAULT_SHAPE = "built-in torus(major_radius=1.0, minor_radius=0.25, n_major=48, n_minor=16)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of `ddgjax info` to `parser` and make `run_info` its action."""
    parser.add_argument(
        "mesh",
        nargs="?",
        default=None,
        help=f"mesh file: triangles (.obj, .off, .ply, .stl) or tets (.msh, .vtk, .vtu, .mesh, .meshb, .ele, .node); "
        f"default: the {_DEFAULT_SHAPE}",
    )
    parser.add_argument(
        "--area-tol",
        type=float,
        default=1e-12,
        help="relative tolerance for zero-area faces: area <= tol * (longest edge)^2 (default 1e-12)",
    )
    parser.add_argument(
        "--volume-tol",
        type=float,
        default=1e-12,
        help="tet meshes: relative tolerance for degenerate tets: |volume| <= tol * (longest edge)^3 (default 1e-12)",
    )
    parser.add_argument(
        "--output", default=None, help="also draw the Gaussian and mean curvature to this figure file (triangle meshes)"
    )
    parser.add_argument("--up", choices=("x", "y", "z"), default="z", help="the axis that points up in the figure")
    parser.set_defaults(run=run_info)


@kernel(static_argnames=("oriented",))
def _statistics(mesh: Mesh, *, oriented: bool) -> dict:
    """Every number the report prints, in one compiled call.

    The signed mean and principal curvatures exist only with a consistent orientation (they raise
    `MeshDataError` otherwise); without one (`oriented`, read from the topology before the kernel,
    which sees none) they are left out and the report says why.
    """
    stats = {
        "area": total_area(mesh),
        "volume": enclosed_volume(mesh),
        "defects": vertex_angle_defects(mesh),
        "K": vertex_pointwise_gaussian_curvatures(mesh),
    }
    if oriented:
        stats["H"] = vertex_pointwise_mean_curvatures(mesh)
        stats["principal"] = vertex_principal_curvatures(mesh)
    return stats


def run_info(args: argparse.Namespace) -> int:
    """Print the report of `args.mesh` (or the default shape); exit code 2 with a message on bad input."""
    if args.mesh is not None and is_tet_file(args.mesh):
        return _run_tet_info(args)
    try:
        if args.mesh is None:
            name, mesh = _DEFAULT_SHAPE, torus(major_radius=1.0, minor_radius=0.25, n_major=48, n_minor=16, dtype=jnp.float64)
        else:
            name, mesh = args.mesh, load_mesh(args.mesh, dtype=jnp.float64)
        report = check_mesh(mesh, area_tol=args.area_tol)
    except (OSError, DDGInputError, MeshDataError) as error:
        print(f"ddgjax info: error: {error}", file=sys.stderr)
        return 2
    stats = jax.tree_util.tree_map(np.asarray, _statistics(mesh, oriented=mesh.topology.is_oriented))
    print(format_info(name, report, stats))
    if args.output is not None and not _draw(mesh, name, report, stats, args):
        return 2
    return 0


def _draw(mesh: Mesh, name: str, report: MeshReport, stats: dict, args: argparse.Namespace) -> bool:
    """The pointwise Gaussian (and mean) curvature on the mesh: diverging colours centred on 0 for a field that
    changes sign, else sequential ones; limits at the 2nd and 98th percentiles."""
    # Imported here: matplotlib is only needed when a figure is written.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..plot import plot_mesh_function

    referenced = np.ones(report.n_vertices, dtype=bool)
    referenced[report.unreferenced_vertices] = False
    panels = [("Gaussian curvature K", stats["K"])]
    if "H" in stats:
        panels.append(("mean curvature H", stats["H"]))
    figure = Figure(figsize=(4.8 * len(panels) + 0.6, 4.4), layout="constrained")
    FigureCanvasAgg(figure)
    for index, (title, values) in enumerate(panels):
        axes = figure.add_subplot(1, len(panels), index + 1)
        # Percentiles: a few extreme vertices (creases, cone tips) would wash out the rest of the field.
        low, high = np.percentile(values[referenced], [2, 98])
        if low < 0 < high:
            low, high, cmap = -max(-low, high), max(-low, high), "RdBu_r"
        else:
            cmap = "viridis"
        collection = plot_mesh_function(axes, mesh, values, up=args.up, cmap=cmap, vmin=low, vmax=high)
        axes.set_title(title, fontsize=10)
        figure.colorbar(collection, ax=axes, shrink=0.8)
    figure.suptitle(name, fontsize=10)
    return write_figure(figure, args.output, args.command)


def format_info(name: str, report: MeshReport, stats: dict) -> str:
    """The text of `ddgjax info` from a `MeshReport` and the computed statistics."""
    referenced = np.ones(report.n_vertices, dtype=bool)
    referenced[report.unreferenced_vertices] = False
    chi = report.euler_characteristic
    total_defect = float(np.sum(stats["defects"]))
    lines = [f"mesh: {name}", str(report), "", f"area: {float(stats['area']):.10g}"]
    if report.is_closed and report.is_oriented:
        lines.append(f"enclosed volume: {float(stats['volume']):.10g}")
    else:
        lines.append("enclosed volume: - (needs a closed, oriented mesh)")
    lines += [
        "",
        "Gauss-Bonnet: sum of angle defects = 2 pi chi",
        f"  sum of defects {total_defect:.15g}   2 pi chi {2 * np.pi * chi:.15g}   difference {total_defect - 2 * np.pi * chi:.3e}",
        "",
        "pointwise curvature (Voronoi dual areas; referenced vertices)      min          median       max",
    ]
    rows = [("Gaussian curvature K", stats["K"])]
    if "H" in stats:
        rows += [
            ("mean curvature H (dihedral angles)", stats["H"]),
            ("principal curvature k1", stats["principal"][:, 0]),
            ("principal curvature k2", stats["principal"][:, 1]),
        ]
    for label, values in rows:
        values = values[referenced]
        lines.append(f"  {label:<62s} {np.min(values):>12.5g} {np.median(values):>12.5g} {np.max(values):>12.5g}")
    if "H" not in stats:
        problem = (
            f"{report.nonmanifold_edges.size} non-manifold edges"
            if report.nonmanifold_edges.size
            else f"{report.inconsistent_edges.size} inconsistently oriented edges"
        )
        lines.append(
            "  mean curvature H, principal curvatures k1, k2: undefined (their sign needs consistently "
            f"oriented faces; this mesh has {problem})"
        )
    return "\n".join(lines)


@kernel
def _tet_statistics(tet_mesh: TetMesh, boundary: Mesh | None) -> dict:
    """The numbers of the tet report, in one compiled call (`boundary`: the boundary surface, `None` when there is none)."""
    stats = {"volumes": tet_signed_volumes(tet_mesh), "dihedral": tet_dihedral_angles(tet_mesh)}
    if boundary is not None:
        stats["area"] = total_area(boundary)
        stats["enclosed"] = enclosed_volume(boundary)
    return stats


def _run_tet_info(args: argparse.Namespace) -> int:
    """`ddgjax info` on a tet mesh file: the report of `check_tet_mesh` and the statistics of `format_tet_info`."""
    try:
        if args.output is not None:
            raise DDGInputError(f"--output: figures are drawn for triangle meshes only; {args.mesh!r} is read as a tet mesh")
        tet_mesh = load_tet_mesh(args.mesh, dtype=jnp.float64)
        report = check_tet_mesh(tet_mesh, volume_tol=args.volume_tol)
    except (OSError, DDGInputError) as error:
        surfaces = " (triangle meshes: .obj, .off, .ply, .stl)" if "unknown tet mesh format" in str(error) else ""
        print(f"ddgjax info: error: {error}{surfaces}", file=sys.stderr)
        return 2
    boundary = tet_mesh.boundary_mesh() if report.n_boundary_triangles else None
    stats = jax.tree_util.tree_map(np.asarray, _tet_statistics(tet_mesh, boundary))
    print(format_tet_info(args.mesh, report, stats))
    return 0


def format_tet_info(name: str, report: TetMeshReport, stats: dict) -> str:
    """The text of `ddgjax info` on a tet mesh from a `TetMeshReport` and the computed statistics."""
    lines = [f"tet mesh: {name}", str(report), ""]
    if "area" in stats:
        enclosed = float(stats["enclosed"])
        lines += [
            f"boundary surface: area {float(stats['area']):.10g}, enclosed volume {enclosed:.10g} "
            f"(sum of tet volumes minus it: {report.volume - enclosed:.3e})",
            "",
        ]
    degrees = np.degrees(stats["dihedral"])
    lines.append("per tet                                   min          median       max")
    for label, values in (("signed volume", stats["volumes"]), ("dihedral angle (degrees)", degrees)):
        lines.append(f"  {label:<36s} {np.min(values):>12.5g} {np.median(values):>12.5g} {np.max(values):>12.5g}")
    return "\n".join(lines)
