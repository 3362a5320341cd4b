"""The `ddgjax poisson` subcommand (ddgjax/_cli/poisson.py), driven through `ddgjax.cli.main`, and the
mesh figure it draws with (`ddgjax.plot.plot_mesh_function`)."""

from __future__ import annotations

import re
from unittest import mock

import jax.numpy as jnp
import matplotlib.image
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection, TriMesh
from matplotlib.figure import Figure

from ddgjax import RESULTS, DDGInputError, Solution
from ddgjax.mesh import disk
from ddgjax.plot import TOP_VIEW, is_flat, plot_mesh_function
from ddgjax.volume import TetMesh, save_tet_mesh, tet_ball

from conftest import data_path, run_cli

ROWS = ("mesh", "problem", "solver", "time", "relative residual", "energy", "Dirichlet energy", "solution")


_run = run_cli


def _table(text: str) -> dict[str, str]:
    """`{row label: text}` of the printed table."""
    rows = {}
    for line in text.splitlines():
        label = next((name for name in sorted(ROWS + ("error",), key=len, reverse=True) if line.startswith(name + " ")), None)
        if label:
            rows[label] = line[len(label) :].strip()
    return rows


def _number(text: str) -> float:
    return float(text.split()[0])


def _image_is_a_picture(path, min_colours=100):
    image = matplotlib.image.imread(path)
    assert image.shape[0] > 400 and image.shape[1] > 600
    # Not blank: many distinct colours (a colour map across the mesh, anti-aliased text).
    rgb = np.round(image[..., :3] * 255).astype(np.uint32)
    assert np.unique((rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]).size > min_colours


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    """`ddgjax poisson` with every default: -Delta phi = 1 on the built-in unit disk, with the figure."""
    output = tmp_path_factory.mktemp("poisson") / "poisson.png"
    return (*_run(["poisson", "--output", str(output)]), output)


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_default_run_prints_the_table_and_writes_the_figure(default_run):
    status, out, err, output = default_run
    assert status == 0, err
    rows = _table(out)
    assert set(ROWS) <= set(rows), out
    assert rows["mesh"].startswith("built-in disk(n_rings=24): 1801 vertices, 3456 faces, 1 boundary loop")
    assert rows["problem"] == "-Delta phi = 1 (rho = -1), phi = 0 on the 144 boundary vertices"
    assert re.match(r"\S+ s first call \(compilation included\), \S+ ms again", rows["time"])
    assert _number(rows["relative residual"]) < 1e-10
    # The unit disk's solution (1 - r^2)/4 has Dirichlet energy int |grad phi|^2 / 2 = pi / 16, and
    # the minimised energy is its negative; 2e-3: the inscribed 144-gon's area deficit is O(h^2).
    assert abs(_number(rows["Dirichlet energy"]) - np.pi / 16) < 2e-3
    assert abs(_number(rows["energy"]) + _number(rows["Dirichlet energy"])) < 1e-12
    # On the rotationally symmetric built-in disk the quadratic is reproduced to round-off.
    assert _number(rows["error"]) < 1e-12
    assert f"figure written to {output}" in out
    _image_is_a_picture(output)


@pytest.mark.slow
def test_closed_sphere_with_a_spherical_harmonic():
    status, out, err = _run(["poisson", "sphere", "--resolution", "3", "--no-plot"])
    assert status == 0, err
    rows = _table(out)
    assert rows["mesh"].startswith("built-in icosphere(subdivisions=3): 642 vertices, 1280 faces, 0 boundary loops")
    assert "zero-mean phi" in rows["problem"] and "P2" in rows["problem"]
    assert _number(rows["relative residual"]) < 1e-10
    # Delta P2 = -6 P2 on the unit sphere; 2e-3: the discretisation error of a 642-vertex icosphere.
    assert _number(rows["error"]) < 2e-3
    assert "figure written" not in out


@pytest.mark.slow
def test_harmonic_interpolation_on_the_disk(tmp_path):
    output = tmp_path / "harmonic.png"
    status, out, err = _run(["poisson", "--harmonic", "--resolution", "12", "--output", str(output)])
    assert status == 0, err
    rows = _table(out)
    assert rows["problem"] == "harmonic: L phi = 0 inside, phi = (x^2 - y^2) / R^2 on the 72 boundary vertices"
    assert rows["solution"] == "min -1, max 1"  # the maximum principle: extremes on the boundary
    # x^2 - y^2 is harmonic; the discrete extension is O(h^2) from it (h = 1/12).
    assert _number(rows["error"]) < 2e-3
    assert _number(rows["energy"]) == _number(rows["Dirichlet energy"])  # rho = 0
    _image_is_a_picture(output)


@pytest.mark.parametrize(
    ("name", "argv", "problem"),
    [
        ("hemisphere.obj", ["--harmonic"], "harmonic: L phi = 0 inside"),
        ("sphere.obj", ["--rho", "source"], "Delta phi = delta at vertex"),
    ],
)
@pytest.mark.slow
def test_a_mesh_file(tmp_path, name, argv, problem):
    path = data_path("meshes", name)
    output = tmp_path / "poisson.png"
    status, out, err = _run(["poisson", str(path), *argv, "--output", str(output)])
    assert status == 0, err
    rows = _table(out)
    assert rows["mesh"].startswith(f"{name}: ")
    assert rows["problem"].startswith(problem)
    assert _number(rows["relative residual"]) < 1e-10
    assert "error" not in rows  # no exact solution for a file
    _image_is_a_picture(output)


def test_help():
    status, out, _ = _run(["poisson", "--help"])
    assert status == 0
    for option in ("--rho", "--harmonic", "--boundary", "--solver", "--mass", "--output", "--view", "ball", ".msh"):
        assert option in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["no/such/mesh.obj"], "MESH: expected one of disk, sphere, ball or an existing mesh file"),
        (["{bad_file}"], "bad.obj"),
        (["{bad_file}", "--resolution", "3"], "--resolution: applies to the built-in shapes"),
        (["sphere", "--rho", "one"], "--rho one: without Dirichlet boundary values"),
        (["disk", "--boundary", "neumann", "--rho", "one"], "--rho one: without Dirichlet boundary values"),
        (["disk", "--harmonic", "--boundary", "neumann"], "--boundary: applies to the Poisson problem"),
    ],
)
def test_bad_input_is_a_clean_error(tmp_path, argv, message):
    bad_file = tmp_path / "bad.obj"
    bad_file.write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    output = tmp_path / "x.png"
    status, out, err = _run(["poisson", "--output", str(output), *(a.format(bad_file=bad_file) for a in argv)])
    assert status == 2
    assert message in err and "Traceback" not in err + out
    assert not output.exists()


@pytest.mark.parametrize(
    "argv",
    [["--harmonic", "--rho", "y2"], ["--rho", "sin"], ["--resolution", "0"], ["--view", "up"], ["--solver", "lu"], ["--up", "w"]],
)
def test_bad_options_are_usage_errors(argv):
    status, _, err = _run(["poisson", *argv])
    assert status == 2 and "usage:" in err


def test_an_unwritable_output_is_a_clean_error(default_run, tmp_path):
    # The default problem again: its compiled program is reused.
    output = tmp_path / "missing" / "poisson.png"
    status, out, err = _run(["poisson", "--output", str(output)])
    assert status == 2
    assert "--output: could not write" in err and "Traceback" not in err
    assert _table(out)["problem"] == _table(default_run[1])["problem"]


def test_a_failed_solve_is_reported():
    # The outcome of solve_poisson(..., throw=False): its RESULTS message, no table.
    def failing(problem, args):
        return Solution(value=jnp.zeros(problem.mesh.n_vertices), result=RESULTS.singular, stats={})

    with mock.patch("ddgjax._cli.poisson._solve", side_effect=failing):
        status, out, err = _run(["poisson", "--resolution", "2", "--no-plot"])
    assert status == 1 and out == ""
    assert "the solve failed: The solution does not solve the system" in err and "try --solver" in err
    # A failure raised inside the solve (equinox's runtime error): its first line, no traceback.
    failure = RuntimeError("INTERNAL: CpuCallback error\n  ...\n_EquinoxRuntimeError: The solution does not solve the system.\n")
    with mock.patch("ddgjax._cli.poisson._solve", side_effect=failure):
        status, out, err = _run(["poisson", "--resolution", "2", "--no-plot"])
    assert status == 1 and out == ""
    assert "the solve failed: The solution does not solve the system." in err and "Traceback" not in err


# --- solids ------------------------------------------------------------------------------------------


def _libigl_torsion(ball: TetMesh) -> tuple[float, float]:
    """Dirichlet energy and maximum of `-Delta u = 1`, `u = 0` on the boundary, from libigl's cotan Laplacian
    and Voronoi mass matrix of the tets, solved by SciPy."""
    import igl
    import scipy.sparse.linalg

    vertices, tets = np.asarray(ball.vertices), np.asarray(ball.tets, dtype=np.int64)
    laplacian = -igl.cotmatrix(vertices, tets).tocsr()
    load = igl.massmatrix(vertices, tets, igl.MASSMATRIX_TYPE_VORONOI) @ np.ones(ball.n_vertices)
    free = np.setdiff1d(np.arange(ball.n_vertices), ball.topology.boundary_vertices)
    phi = np.zeros(ball.n_vertices)
    phi[free] = scipy.sparse.linalg.spsolve(laplacian[free][:, free].tocsc(), load[free])
    return 0.5 * phi @ laplacian @ phi, phi.max()


def test_torsion_in_the_ball(tmp_path):
    output = tmp_path / "ball.png"
    status, out, err = _run(["poisson", "ball", "--resolution", "4", "--output", str(output)])
    assert status == 0, err
    rows = _table(out)
    assert rows["mesh"] == "built-in tet_ball(n_layers=4): 309 vertices, 1280 tets, 320 boundary triangles"
    assert rows["problem"] == "-Delta phi = 1 (rho = -1), phi = 0 on the 162 boundary vertices"
    assert _number(rows["relative residual"]) < 1e-10
    # (1 - r^2)/6: 2.3e-3 measured at 4 layers (the max norm converges at rate ~1.5, ddgjax.volume.tet_ball).
    assert _number(rows["error"]) < 3e-3 and "(1 - r^2)/6" in rows["error"]
    # The same problem solved independently (libigl's operators, SciPy's solve), to the digits the table
    # prints (10 significant for the energy, 6 for the maximum).
    energy, maximum = _libigl_torsion(tet_ball(4))
    assert abs(_number(rows["Dirichlet energy"]) / energy - 1) < 1e-9
    assert rows["solution"].startswith("min 0, max ") and abs(float(rows["solution"].split()[-1]) - maximum) <= 5e-7
    _image_is_a_picture(output)


def _without_mesh_and_time(rows: dict[str, str]) -> dict[str, str]:
    return {label: text for label, text in rows.items() if label not in ("mesh", "time")}


@pytest.mark.parametrize("suffix", [".msh", *(pytest.param(s, marks=pytest.mark.slow) for s in (".vtu", ".mesh", ".ele"))])
def test_a_tet_mesh_file_round_trip(tmp_path, suffix):
    ball = tet_ball(3)
    path = tmp_path / f"ball{suffix}"
    save_tet_mesh(path, ball)
    status, out, err = _run(["poisson", str(path), "--harmonic", "--no-plot"])
    assert status == 0, err
    rows = _table(out)
    assert rows["mesh"].startswith(f"ball{suffix}: {ball.n_vertices} vertices, {ball.n_tets} tets, ")
    # The same vertices in the same order: the file's table is the built-in ball's, to the last digit,
    # and x^2 - y^2, harmonic in space, is the exact solution in any solid (at rate ~1.5 in the max norm).
    status, built_in, err = _run(["poisson", "ball", "--resolution", "3", "--harmonic", "--no-plot"])
    assert status == 0, err
    assert _without_mesh_and_time(rows) == _without_mesh_and_time(_table(built_in))
    assert _number(rows["error"]) < 0.05  # the discretisation error of 3 layers: measured 4.1e-2 (2.9e-2 at 4)


def test_a_tet_mesh_file_without_exact_solution(tmp_path):
    path = tmp_path / "ball.vtk"
    save_tet_mesh(path, tet_ball(3))
    output = tmp_path / "ball.png"
    status, out, err = _run(["poisson", str(path), "--output", str(output)])
    assert status == 0, err
    rows = _table(out)
    assert rows["problem"] == "-Delta phi = 1 (rho = -1), phi = 0 on the 92 boundary vertices"
    assert "error" not in rows  # the exact solution is the built-in unit ball's only
    # The slice and the boundary surface share the solution's colours: fewer colours than a ramp and an error map.
    _image_is_a_picture(output, min_colours=50)


@pytest.fixture
def tet_files(tmp_path) -> dict[str, str]:
    """`{name: path}`: a good tet file (`ball`), one with a `flat` tet, one meshio cannot read, one of an `unknown` suffix."""
    ball = tet_ball(2)
    vertices = np.concatenate([np.asarray(ball.vertices), [[2.0, 0, 0], [3, 0, 0], [2, 1, 0], [3, 1, 0]]])
    tets = np.concatenate([np.asarray(ball.tets), [np.arange(4) + ball.n_vertices]])
    paths = {"ball": tmp_path / "ball.msh", "flat": tmp_path / "flat.msh", "garbage": tmp_path / "garbage.msh"}
    paths["unknown"] = tmp_path / "ball.xyz"
    save_tet_mesh(paths["ball"], ball)
    save_tet_mesh(paths["flat"], TetMesh.from_arrays(vertices, tets))
    paths["garbage"].write_text("not a mesh\n")
    paths["unknown"].write_text("not a mesh\n")
    return {name: str(path) for name, path in paths.items()}


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["{ball}", "--resolution", "3"], "--resolution: applies to the built-in shapes"),
        (["ball", "--boundary", "neumann", "--rho", "one"], "--rho one: without Dirichlet boundary values"),
        (["{flat}"], "tets [160] (1 in all) have zero or near-zero volume"),
        (["{garbage}"], "garbage.msh: path: meshio cannot read"),
        (["{unknown}"], "unknown tet mesh format '.xyz'"),
        (["{unknown}"], "(read as a tet mesh: triangle meshes are .obj, .off, .ply, .stl files)"),
    ],
)
def test_bad_input_on_a_solid_is_a_clean_error(tet_files, tmp_path, argv, message):
    output = tmp_path / "x.png"
    status, out, err = _run(["poisson", "--output", str(output), *(a.format_map(tet_files) for a in argv)])
    assert status == 2
    assert message in err and "Traceback" not in err + out
    assert not output.exists()


# --- plot_mesh_function ----------------------------------------------------------------------------


@pytest.fixture
def axes():
    figure = Figure()
    FigureCanvasAgg(figure)
    return figure.add_subplot()


def test_plot_mesh_function_vertex_values_gouraud(axes, icosphere1):
    mesh = icosphere1
    values = np.asarray(mesh.vertices)[:, 2]
    collection = plot_mesh_function(axes, mesh, values, cmap="magma")
    assert isinstance(collection, TriMesh)
    assert collection.get_cmap().name == "magma"
    assert collection.norm.vmin == values.min() and collection.norm.vmax == values.max()
    assert not axes.axison and axes.get_aspect() == 1.0
    axes.figure.canvas.draw()


def test_plot_mesh_function_paints_back_to_front(axes, icosphere1):
    mesh = icosphere1
    values = np.arange(mesh.n_faces, dtype=float)  # one value per face: flat shading
    collection = plot_mesh_function(axes, mesh, values, view=TOP_VIEW, vmin=0, vmax=100, edgecolor="k")
    assert isinstance(collection, PolyCollection)
    assert collection.norm.vmin == 0 and collection.norm.vmax == 100
    # Seen from +z, the last face painted is the nearest: the largest mean z.
    face_heights = np.asarray(mesh.vertices)[np.asarray(mesh.faces), 2].mean(axis=1)
    painted = np.asarray(collection.get_array(), dtype=int)
    assert face_heights[painted[-1]] == face_heights.max() and face_heights[painted[0]] == face_heights.min()
    assert np.all(np.diff(face_heights[painted]) >= -1e-15)
    np.testing.assert_array_equal(np.sort(painted), values)


def test_plot_mesh_function_views(axes, icosphere1):
    flat, round_ = disk(3), icosphere1
    assert is_flat(flat) and not is_flat(round_)
    values = np.asarray(flat.vertices)[:, 0]
    plot_mesh_function(axes, flat, values, shading="flat")  # flat mesh: seen from above, so x spans the width
    x_limits = axes.get_xlim()
    assert x_limits[0] <= -1 and x_limits[1] >= 1
    for up in ("x", "y", "z"):
        plot_mesh_function(axes, round_, np.asarray(round_.vertices)[:, 0], view=(30, 10), up=up)


def test_plot_mesh_function_bad_input(axes, without_type_checker):
    mesh = disk(2)
    with pytest.raises(DDGInputError, match=r"values: expected shape \(19,\) .* or \(24,\)"):
        plot_mesh_function(axes, mesh, np.zeros(5))
    with pytest.raises(DDGInputError, match="shading: expected one of"):
        plot_mesh_function(axes, mesh, np.zeros(19), shading="phong")
    with pytest.raises(DDGInputError, match="up: expected one of"):
        plot_mesh_function(axes, mesh, np.zeros(19), up="w")
    with pytest.raises(DDGInputError, match="mesh"):
        plot_mesh_function(axes, np.zeros((3, 3)), np.zeros(3))
