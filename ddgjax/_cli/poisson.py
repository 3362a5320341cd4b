"""`ddgjax poisson [MESH]`: solve a Poisson or harmonic problem on a mesh and draw the solution.

The Poisson problem is the reading report's `Delta phi = rho` with `Delta = -M^{-1} L`, solved by
`ddgjax.pde.solve_poisson` (`L phi = -M rho`); `--harmonic` solves the harmonic interpolation
problem instead (`ddgjax.pde.harmonic_interpolation`, `L phi = 0` away from the prescribed
vertices). The built-in shapes need no file: `disk` (the unit disk, with a boundary) and `sphere`
(the unit icosphere, closed); on them the printed table also compares with the exact solution
where one is known. The figure shows the solution coloured on the mesh (with isolines on a flat
mesh) beside its error, or the right-hand side when no exact solution is known, drawn with
`ddgjax.plot.plot_mesh_function` on the Agg canvas (no pyplot, no display).

Solids: the built-in `ball` (the unit ball, `ddgjax.volume.tet_ball`) and tet mesh files
(`ddgjax.volume.load_tet_mesh`; a file is a tet mesh unless it is a triangle mesh's `.obj`, `.off`,
`.ply` or `.stl`) are solved the same way with the solid's `L` and `M` (`ddgjax.volume`), the
boundary being the boundary surface's vertices. `--rho one` in the unit ball is exact at
`(1 - r^2) / 6`; `--harmonic` prescribes the same `(a^2 - b^2) / R^2`, which is harmonic in 3-D, so
it is its own exact extension in every solid. A solid's figure is drawn on the slice through the
middle of its bounding box across the `--up` axis (`ddgjax.volume.plane_section`), beside the
error on the same slice or, with no exact solution, the boundary surface coloured by the solution.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import laplacian as surface_operators
from .. import volume
from .._compile import kernel
from .._errors import DDGInputError, MeshDataError
from .._options import BOUNDARY_CONDITIONS, MASS_MATRICES
from .._results import RESULTS, Solution
from ..mesh import Mesh, disk, icosphere
from ..pde import solve_poisson
from ..solve.internal import auto_solver
from ..volume import TetMesh, tet_ball
from ._common import SURFACE_SUFFIXES, add_output_argument, load_cli_mesh, write_figure

SHAPES = {"disk": "unit disk (with boundary)", "sphere": "unit icosphere (closed)", "ball": "unit ball (a solid: tets)"}
DEFAULT_RESOLUTION = {"disk": 24, "sphere": 4, "ball": 8}
RHOS = ("auto", "one", "y2", "source")
SOLVERS = {
    "cholesky": "cholesky (CHOLMOD through sparsax)",
    "superlu": "superlu (SciPy's SuperLU)",
    "cg": "cg (conjugate gradient in JAX, Jacobi preconditioner)",
    "pyamg": "pyamg (SciPy's conjugate gradient with pyamg's V-cycle)",
}
RHO_HELP = {
    "one": "rho = -1, i.e. -Delta phi = 1 (torsion problem; exact (1 - r^2)/4 on the unit disk, (1 - r^2)/6 in the unit ball)",
    "y2": "rho = P2(cos theta) = (3 cos^2 theta - 1)/2 of the direction from the bounding-box centre, a degree-2 "
    "spherical harmonic (exact phi = -rho/6 on the unit sphere)",
    "source": "a unit point source at the free vertex nearest the bounding-box centre (rho = 1/area there, 0 "
    "elsewhere): a discrete Green's function",
}


def _at_least(minimum: int):
    """argparse type: an integer >= `minimum`."""

    def parse(text: str) -> int:
        value = int(text)
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}")
        return value

    return parse


def _view(text: str) -> tuple[float, float]:
    """argparse type for `--view`: two finite numbers separated by a comma."""
    try:
        azimuth, elevation = (float(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected AZIMUTH,ELEVATION in degrees, e.g. -60,20, got {text!r}") from None
    if not (np.isfinite(azimuth) and np.isfinite(elevation)):
        raise argparse.ArgumentTypeError(f"expected finite angles, got {text!r}")
    return azimuth, elevation


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of `ddgjax poisson` to `parser` and make `run_poisson` its action."""
    parser.formatter_class = argparse.ArgumentDefaultsHelpFormatter
    parser.add_argument(
        "mesh",
        nargs="?",
        default="disk",
        help="built-in shape: " + ", ".join(f"{name} ({what})" for name, what in SHAPES.items()) + "; or a mesh file: "
        f"triangles ({', '.join(SURFACE_SUFFIXES)}) or tets (.msh, .vtk, .vtu, .mesh, .meshb, .ele, .node)",
    )
    parser.add_argument(
        "--resolution",
        type=_at_least(1),
        default=None,
        help="size of the built-in shape: rings of the disk (default 24: 1,801 vertices), subdivisions of the "
        "icosphere (default 4: 2,562 vertices), layers of the ball (default 8: 2,057 vertices)",
    )
    problem = parser.add_mutually_exclusive_group()
    problem.add_argument(
        "--rho",
        choices=RHOS,
        default="auto",
        help="right-hand side of Delta phi = rho: "
        + "; ".join(f"{name}: {text}" for name, text in RHO_HELP.items())
        + "; auto: one with Dirichlet boundary values, y2 otherwise",
    )
    problem.add_argument(
        "--harmonic",
        action="store_true",
        help="harmonic interpolation instead (rho = 0): on a mesh with boundary, the boundary takes the values "
        "(a^2 - b^2) / R^2 of the two longest bounding-box coordinates a, b about its centre (x^2 - y^2 on the "
        "unit disk, whose harmonic extension is exact; in a solid, where it is harmonic, exact too); on a closed "
        "mesh, the extreme vertices along the longest bounding-box axis take 0 and 1",
    )
    parser.add_argument(
        "--boundary",
        choices=BOUNDARY_CONDITIONS,
        default="dirichlet",
        help="boundary condition of the Poisson problem on a mesh with boundary: phi = 0 there (dirichlet), or "
        "zero normal derivative (neumann: rho made compatible, zero-mean phi, as on a closed mesh)",
    )
    parser.add_argument("--mass", choices=MASS_MATRICES, default="voronoi", help="mass matrix M")
    parser.add_argument(
        "--solver",
        choices=("auto",) + tuple(SOLVERS),
        default="auto",
        help="backend of the linear solve: cholesky (CHOLMOD through sparsax), superlu (SciPy), cg (conjugate gradient in JAX with "
        "an AMG V-cycle), pyamg (SciPy's CG with pyamg's V-cycle), auto (cholesky on CPU when sparsax is installed, "
        "else superlu; cg on a GPU)",
    )
    parser.add_argument(
        "--view",
        type=_view,
        default=None,
        metavar="AZIMUTH,ELEVATION",
        help="camera angles of the figure in degrees; default: from above for a mesh flat in z and for a solid's "
        "slice, else -60,20",
    )
    parser.add_argument(
        "--up",
        choices=("x", "y", "z"),
        default="z",
        help="the mesh's up axis in the figure (y for spot.obj); a solid is sliced across it",
    )
    add_output_argument(parser, "poisson")
    parser.add_argument("--no-plot", action="store_true", help="print the table only, write no figure")
    parser.set_defaults(run=run_poisson)


class Problem(NamedTuple):
    """What is solved: the mesh, the right-hand side, the Dirichlet data, and how to describe them."""

    name: str  # the mesh, for the table and the title
    mesh: Mesh | TetMesh  # a surface, or a solid
    rho: np.ndarray  # (nv,) pointwise right-hand side (zeros for --harmonic)
    fixed: np.ndarray  # (n_fixed,) Dirichlet vertices
    values: np.ndarray  # (n_fixed,) their values
    statement: str  # the equation and boundary condition, in words
    exact: np.ndarray | None  # (nv,) exact solution at the vertices, where one is known
    exact_name: str
    source: int | None = None  # the vertex of a point source (--rho source)


def _mesh(args) -> tuple[str, Mesh | TetMesh, str | None]:
    """The mesh named by the positional argument: (description, mesh, built-in shape name or None)."""
    if args.mesh in SHAPES:
        resolution = args.resolution or DEFAULT_RESOLUTION[args.mesh]
        if args.mesh == "disk":
            return f"built-in disk(n_rings={resolution})", disk(resolution, dtype=jnp.float64), "disk"
        if args.mesh == "ball":
            return f"built-in tet_ball(n_layers={resolution})", tet_ball(resolution, dtype=jnp.float64), "ball"
        return f"built-in icosphere(subdivisions={resolution})", icosphere(resolution, dtype=jnp.float64), "sphere"
    if args.resolution is not None:
        raise DDGInputError(f"--resolution: applies to the built-in shapes ({', '.join(SHAPES)}), not to the file {args.mesh!r}")
    if not os.path.isfile(args.mesh):
        raise DDGInputError(f"MESH: expected one of {', '.join(SHAPES)} or an existing mesh file, got {args.mesh!r}")
    return *load_cli_mesh(args.mesh, solids=True), None


def _operators(mesh: Mesh | TetMesh):
    """The package whose `cotan_laplacian`, `mass_matrix(mass=)` and `dirichlet_energy` act on `mesh`:
    `ddgjax.laplacian` for a surface, `ddgjax.volume` for a solid."""
    return volume if isinstance(mesh, TetMesh) else surface_operators


def _frame(mesh: Mesh | TetMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`(referenced, centre, axes)`: the mask of the vertices the faces or tets use, the centre of their
    bounding box and its axes, longest first."""
    vertices = np.asarray(mesh.vertices)
    referenced = np.ones(mesh.n_vertices, dtype=bool)
    referenced[mesh.topology.unreferenced_vertices] = False
    low, high = vertices[referenced].min(axis=0), vertices[referenced].max(axis=0)
    return referenced, (low + high) / 2, np.argsort(-(high - low), kind="stable")


def _problem(args) -> Problem:
    name, mesh, shape = _mesh(args)
    topology = mesh.topology
    vertices = np.asarray(mesh.vertices)
    referenced, centre, axes = _frame(mesh)
    boundary = np.asarray(topology.boundary_vertices, dtype=np.int64)
    zeros = np.zeros(mesh.n_vertices)
    if args.harmonic:
        if args.boundary != "dirichlet":
            raise DDGInputError("--boundary: applies to the Poisson problem; --harmonic prescribes its own values")
        if boundary.size:
            a, b = (vertices[:, axes[:2]] - centre[axes[:2]]).T
            data = (a**2 - b**2) / np.max(a[boundary] ** 2 + b[boundary] ** 2)
            coordinates = "xyz"[axes[0]] + "^2 - " + "xyz"[axes[1]] + "^2"
            statement = f"harmonic: L phi = 0 inside, phi = ({coordinates}) / R^2 on the {boundary.size} boundary vertices"
            # a^2 - b^2 is harmonic in the plane and in space, not on a curved surface.
            exact = data if shape == "disk" or isinstance(mesh, TetMesh) else None
            return Problem(name, mesh, zeros, boundary, data[boundary], statement, exact, f"({coordinates})")
        along = np.where(referenced, vertices[:, axes[0]], np.nan)
        ends = np.array([np.nanargmin(along), np.nanargmax(along)])
        statement = f"harmonic: L phi = 0 except phi = 0, 1 at vertices {ends[0]}, {ends[1]} (extremes along {'xyz'[axes[0]]})"
        return Problem(name, mesh, zeros, ends, np.array([0.0, 1.0]), statement, None, "")
    fixed = boundary if args.boundary == "dirichlet" else np.zeros(0, dtype=np.int64)
    rho_kind = args.rho if args.rho != "auto" else ("one" if fixed.size else "y2")
    if rho_kind == "one" and not fixed.size:
        raise DDGInputError(
            "--rho one: without Dirichlet boundary values a constant right-hand side is removed by the compatibility "
            "condition (int rho = 0) and the solution is 0; choose --rho y2 or source, or a mesh with boundary"
        )
    condition = f"phi = 0 on the {fixed.size} boundary vertices" if fixed.size else "zero-mean phi, rho made compatible"
    if boundary.size and not fixed.size:
        condition = "Neumann boundary, " + condition
    exact, exact_name = None, ""
    if rho_kind == "one":
        rho, equation = -np.ones(mesh.n_vertices), "-Delta phi = 1 (rho = -1)"
        if shape in ("disk", "ball") and fixed.size:  # -Delta (1 - r^2) = 2 d in d dimensions (the disk lies in z = 0)
            dimension = 3 if shape == "ball" else 2
            exact, exact_name = (1 - np.sum(vertices**2, axis=1)) / (2 * dimension), f"(1 - r^2)/{2 * dimension}"
    elif rho_kind == "y2":
        offsets = vertices - centre
        norms = np.linalg.norm(offsets, axis=1)
        cosine = np.divide(offsets[:, 2], norms, out=np.zeros_like(norms), where=norms > 0)
        rho, equation = (3 * cosine**2 - 1) / 2, "Delta phi = P2(cos theta) (degree-2 spherical harmonic)"
        if shape == "sphere":
            exact, exact_name = -rho / 6, "(-P2/6)"
    else:
        free = referenced.copy()
        free[fixed] = False
        if not free.any():
            raise DDGInputError("--rho source: every vertex is a Dirichlet vertex; there is nowhere to put the source")
        distances = np.where(free, np.linalg.norm(vertices - centre, axis=1), np.inf)
        source = int(np.argmin(distances))
        area = float(_operators(mesh).mass_matrix(mesh, mass=args.mass).row_sums()[source])
        rho = np.where(np.arange(mesh.n_vertices) == source, 1.0 / area, 0.0)
        statement = f"Delta phi = delta at vertex {source}, {condition}"
        return Problem(name, mesh, rho, fixed, np.zeros(fixed.size), statement, None, "", source)
    return Problem(name, mesh, rho, fixed, np.zeros(fixed.size), f"{equation}, {condition}", exact, exact_name)


def _solve(problem: Problem, args) -> Solution:
    """`solve_poisson` of the problem, with its outcome returned rather than raised (`throw=False`)."""
    fixed = problem.fixed if problem.fixed.size else None
    return solve_poisson(
        problem.mesh,
        problem.rho,
        fixed_vertices=fixed,
        fixed_values=None if fixed is None else problem.values,
        mass=args.mass,
        solver=args.solver,
        throw=False,
    )


def _measures(problem: Problem, phi, mass: str) -> dict:
    """What the table reports about the solution `phi`: the compatible `rho`, the residual and the energies.

    `residual` is `|L phi + M rho~|` over the free vertices divided by the norm of the right-hand
    side there (`M rho~` and the fixed values' contribution `L phi_D`), with `rho~` the compatible
    right-hand side, restated here from the mesh's components (each without a fixed vertex loses the
    area-weighted mean of `rho`) so that the residual checks the library's answer instead of
    repeating its computation. The Dirichlet energy is the library's (`dirichlet_energy` of the mesh's
    package); the energy adds `phi^T M rho~` to it (`ddgjax.pde.poisson_energy` on a surface).
    """
    mesh, fixed = problem.mesh, problem.fixed
    topology, operators = mesh.topology, _operators(mesh)
    laplacian, mass_matrix_ = operators.cotan_laplacian(mesh), operators.mass_matrix(mesh, mass=mass)
    cells, components = (
        (topology.tets, topology.tet_components) if isinstance(mesh, TetMesh) else (topology.faces, topology.face_components)
    )
    labels = np.full(mesh.n_vertices, topology.n_components, dtype=np.int64)  # unreferenced: a label of their own
    labels[cells.ravel()] = np.repeat(components, cells.shape[1])
    floating = np.ones(topology.n_components + 1, dtype=bool)
    floating[labels[fixed]] = False
    floating[-1] = False
    free = np.ones(mesh.n_vertices, dtype=bool)
    free[fixed] = False
    free[topology.unreferenced_vertices] = False
    compatible, residual, linear = _residual(
        laplacian,
        mass_matrix_,
        phi,
        jnp.asarray(problem.rho),
        jnp.asarray(problem.values),
        labels,
        floating[labels],
        np.flatnonzero(free),
        fixed,
        n_labels=topology.n_components + 1,
    )
    dirichlet = operators.dirichlet_energy(mesh, phi)
    return {"rho": compatible, "residual": residual, "energy": dirichlet + linear, "dirichlet": dirichlet}


@kernel(static_argnames=("n_labels",))
def _residual(laplacian, mass_matrix_, phi, rho, values, labels, floating, free, fixed, *, n_labels: int):
    """`(rho~, residual, phi^T M rho~)` of `_measures`, in one compiled program."""
    integral = jax.ops.segment_sum(mass_matrix_ @ rho, labels, n_labels)
    area = jax.ops.segment_sum(mass_matrix_.row_sums(), labels, n_labels)
    compatible = rho - jnp.where(floating, (integral / jnp.where(area > 0, area, 1.0))[labels], 0.0)
    lift = jnp.zeros_like(phi).at[fixed].set(values)
    load = mass_matrix_ @ compatible
    residual = (laplacian @ phi + load)[free]
    scale = jnp.linalg.norm((load - laplacian @ lift)[free])
    return compatible, jnp.linalg.norm(residual) / jnp.where(scale > 0, scale, 1.0), jnp.sum(phi * load)


def _solve_timed(problem: Problem, args) -> tuple[Solution, float, float]:
    """`_solve` twice: its `Solution`, the first call's time (compilation included) and the second's."""
    times = []
    for _ in range(2):
        start = time.perf_counter()
        solution = jax.block_until_ready(_solve(problem, args))
        times.append(time.perf_counter() - start)
    return solution, times[0], times[1]


def _unknowns(problem: Problem) -> int:
    """The size of the system `solve_poisson` solves: the vertices that are not Dirichlet vertices."""
    return problem.mesh.n_vertices - len(problem.fixed)


def _solver_name(solver: str, n: int) -> str:
    """The backend `linear_solve` runs for `--solver`, in words (`"auto"` resolved as it resolves it)."""
    return SOLVERS[auto_solver(n) if solver == "auto" else solver]


def format_table(problem: Problem, outputs: dict, first: float, second: float, args) -> str:
    """The text `ddgjax poisson` prints: the mesh, the problem and the numbers of its solution."""
    mesh, phi = problem.mesh, outputs["phi"]
    if isinstance(mesh, TetMesh):
        cells = f"{mesh.n_tets} tets, {mesh.topology.boundary_triangles.size} boundary triangles"
    else:
        loops = len(mesh.topology.boundary_loops)
        cells = f"{mesh.n_faces} faces, {loops} boundary loop{'s' * (loops != 1)}"
    rows = [
        ("mesh", f"{problem.name}: {mesh.n_vertices} vertices, {cells}"),
        ("problem", problem.statement),
        ("solver", f"{_solver_name(args.solver, _unknowns(problem))}, {args.mass} mass matrix"),
        ("time", f"{first:.3g} s first call (compilation included), {second * 1e3:.3g} ms again"),
        ("relative residual", f"{float(outputs['residual']):.2e}  (|L phi + M rho| / |right-hand side| on the free vertices)"),
        ("energy", f"{float(outputs['energy']):.10g}  (1/2 phi^T L phi + phi^T M rho, minimised by phi)"),
        ("Dirichlet energy", f"{float(outputs['dirichlet']):.10g}  (1/2 int |grad phi|^2)"),
        ("solution", f"min {phi.min():.6g}, max {phi.max():.6g}"),
    ]
    if problem.exact is not None:
        error = np.abs(phi - problem.exact).max()
        rows.append(("error", f"{error:.2e}  (max |phi - {problem.exact_name}| over the vertices)"))
    width = max(len(label) for label, _ in rows) + 2
    return "\n".join(f"{label:<{width}}{text}" for label, text in rows)


class Panel(NamedTuple):
    """One picture of the figure: `values` at the vertices of `mesh`, drawn from `view` (None: the default)."""

    title: str
    mesh: Mesh
    values: np.ndarray
    cmap: str
    vmin: float | None
    vmax: float | None
    view: tuple[float, float] | None


def _panels(problem: Problem, phi: np.ndarray, rho: np.ndarray, args) -> list[Panel]:
    """The solution beside its error; with no exact solution, beside the right-hand side on a surface and
    the boundary surface coloured by the solution on a solid (whose solution is drawn on a slice)."""
    from ..plot import TOP_VIEW  # imported here as in `_figure`: ddgjax.plot imports matplotlib

    mesh = problem.mesh
    # A point source's solution has a logarithmic spike at the source: colour the rest of it.
    low = np.percentile(phi, 2) if problem.source is not None else None
    clipped = "" if low is None else " (colours clipped below its 2nd percentile)"
    error = None if problem.exact is None else phi - problem.exact
    error_title = f"error $|\\phi - {problem.exact_name}|$"
    if not isinstance(mesh, TetMesh):
        panels = [Panel("solution $\\phi$" + clipped, mesh, phi, "viridis", low, None, args.view)]
        if error is not None:
            panels.append(Panel(error_title, mesh, np.abs(error), "magma", None, None, args.view))
        elif problem.source is None and np.any(rho):
            limit = np.abs(rho).max()
            panels.append(Panel("right-hand side $\\rho$ (made compatible)", mesh, rho, "RdBu_r", -limit, limit, args.view))
        return panels
    # The slice through the middle of the bounding box, across the up axis, seen along its normal
    # (TOP_VIEW looks down the up axis once plot_mesh_function has turned it to z).
    _, centre, _ = _frame(mesh)
    axis = "xyz".index(args.up)
    on_slice = np.column_stack([phi] + ([] if error is None else [error]))
    section, values = volume.plane_section(mesh, on_slice, point=centre, normal=np.eye(3)[axis])
    where = f"on the slice {args.up} = {centre[axis]:.3g}"
    # Both pictures of the solution share its colours (the slice holds only part of its range).
    vmin, vmax = (phi.min() if low is None else low), phi.max()
    panels = [Panel(f"solution $\\phi$ {where}{clipped}", section, values[:, 0], "viridis", vmin, vmax, args.view or TOP_VIEW)]
    if error is not None:
        panels.append(Panel(f"{error_title} {where}", section, np.abs(values[:, 1]), "magma", None, None, args.view or TOP_VIEW))
    else:
        panels.append(
            Panel(
                f"solution $\\phi$ on the boundary surface{clipped}", mesh.boundary_mesh(), phi, "viridis", vmin, vmax, args.view
            )
        )
    return panels


def _figure(problem: Problem, outputs: dict, args):
    """The panels of `_panels` side by side, with isolines on the first where it is seen flat from above."""
    # Imported here: matplotlib is only needed when a figure is written (not for --no-plot or --help).
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..plot import is_flat, plot_mesh_function

    panels = _panels(problem, outputs["phi"], outputs["rho"], args)
    figure = Figure(figsize=(5.6 * len(panels) + 1.0, 5.4), layout="constrained")
    FigureCanvasAgg(figure)
    for index, panel in enumerate(panels):
        axes = figure.add_subplot(1, len(panels), index + 1)
        collection = plot_mesh_function(
            axes, panel.mesh, panel.values, view=panel.view, up=args.up, cmap=panel.cmap, vmin=panel.vmin, vmax=panel.vmax
        )
        # Seen from above, the screen shows the plane's own coordinates x, y.
        if index == 0 and args.view is None and args.up == "z" and is_flat(panel.mesh):
            x, y = np.asarray(panel.mesh.vertices)[:, :2].T
            low = panel.vmin if panel.vmin is not None else panel.values.min()
            levels = np.linspace(low, panel.values.max(), 14)[1:-1]
            axes.tricontour(
                x, y, np.asarray(panel.mesh.faces), panel.values, levels=levels, colors="k", linewidths=0.5, linestyles="solid"
            )
        axes.set_title(panel.title, fontsize=10)
        extend = "min" if problem.source is not None and panel.cmap == "viridis" else "neither"
        figure.colorbar(collection, ax=axes, shrink=0.8, extend=extend)
    figure.suptitle(f"{problem.name}\n{problem.statement}", fontsize=10)
    return figure


def _first_reason(error: Exception) -> str:
    """The message of a failed run, without the traceback JAX's callbacks wrap around it."""
    text = str(error)
    match = re.search(r"EquinoxRuntimeError: (.+)", text)
    return match.group(1).strip() if match else text.strip().splitlines()[0]


def _failed(reason: str, problem: Problem, args) -> int:
    """Report a failed solve on stderr, with what to try instead; the exit status 1."""
    other = "cg" if _solver_name(args.solver, _unknowns(problem)).startswith(("cholesky", "superlu")) else "superlu"
    print(
        f"ddgjax poisson: error: the solve failed: {reason}\n"
        f"(try --solver {other}, or look for degenerate {'tets' if isinstance(problem.mesh, TetMesh) else 'faces'} "
        "with `ddgjax info`)",
        file=sys.stderr,
    )
    return 1


def run_poisson(args: argparse.Namespace) -> int:
    """Action of `ddgjax poisson`: solve, print the table, write the figure; 2 on bad input, 1 on a failed solve."""
    try:
        problem = _problem(args)
    except (OSError, DDGInputError, MeshDataError) as error:
        print(f"ddgjax poisson: error: {error}", file=sys.stderr)
        return 2
    try:
        solution, first, second = _solve_timed(problem, args)
    except (DDGInputError, MeshDataError) as error:
        print(f"ddgjax poisson: error: {error}", file=sys.stderr)
        return 2
    except RuntimeError as error:  # a failure raised inside the solve (equinox's runtime error): reported as a result is
        return _failed(_first_reason(error), problem, args)
    if solution.result != RESULTS.successful:
        return _failed(RESULTS[solution.result], problem, args)
    measures = _measures(problem, solution.value, args.mass)
    outputs = jax.tree_util.tree_map(np.asarray, {"phi": solution.value, **measures})
    print(format_table(problem, outputs, first, second, args))
    if not args.no_plot:
        figure = _figure(problem, outputs, args)
        if not write_figure(figure, args.output, "poisson"):
            return 2
    return 0
