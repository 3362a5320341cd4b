"""Eager calls: every public problem-level function called plainly against the same call in a user's `jit`.

Issue 23's target: a plain (not jitted) call of a problem-level function on a mesh of 2k vertices
or more takes at most 2x the same call inside a user's `jax.jit` (compiled with
`ddgjax.cpu_compiler_options()`, as `benchmarks/solve.py`'s `jit`). An eager call runs the
function's host bookkeeping (cached per connectivity) and then compiled programs cached per size
(`ddgjax._compile.kernel`); the jitted call is one program. The ratio eager / jitted is printed per
function and flagged `> 2x` above the target.

Meshes (`--meshes`, comma-separated): `spot.obj` (2,930 vertices, closed), `hemisphere.obj` (2,051
vertices, one boundary loop) and `disk.obj` (5,000 vertices, a disk) from `../shared/meshes`, and
`icosphere(5)` (10,242 vertices). Functions that need a boundary (parametrisations, Dirichlet
boundaries) run on the meshes with one; host-only builders (`intrinsic_delaunay`, `large_steps`,
`check_mesh`) have no jitted form and print their eager time only.

Each function's eager and jitted calls run interleaved (`timed_interleaved`, after `warmed`:
compilation excluded), min / median ms over `--repeats`. Run:
`python benchmarks/eager.py [--meshes spot.obj,hemisphere.obj,disk.obj,icosphere(5)] [--only NAMES] [--repeats 7]`
(about 15 minutes on 2 cores, most of it compiling each function twice per mesh; `--only
solve_poisson,param.` runs the functions whose names contain one of the substrings).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
from collections.abc import Callable
from dataclasses import dataclass

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, jit, run_sections, timed_interleaved, warmed  # noqa: E402

from ddgjax import dec, fields, geodesics, laplacian, optim, param, pde, spectral  # noqa: E402
from ddgjax import mesh as meshes_  # noqa: E402
from ddgjax.io import load_mesh  # noqa: E402

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "meshes"
TARGET = 2.0


@dataclass(frozen=True)
class Case:
    """One public entry point: `call(mesh, *inputs(mesh))` timed eager and inside `jit`.

    `boundary`: runs only on meshes with a boundary; `host`: a host-only builder (no jitted form).
    `inputs` gives the arrays (pytrees) a user would pass.
    """

    name: str
    call: Callable
    inputs: Callable = lambda mesh: ()
    boundary: bool = False
    host: bool = False


def _rng(mesh):
    return np.random.default_rng(mesh.n_vertices)


def _vertex_values(mesh):
    return (jnp.asarray(_rng(mesh).standard_normal(mesh.n_vertices)),)


def _two_vertex_values(mesh):
    rng = _rng(mesh)
    return jnp.asarray(rng.standard_normal(mesh.n_vertices)), jnp.asarray(rng.standard_normal(mesh.n_vertices))


def _boundary(mesh):
    return np.asarray(mesh.topology.boundary_loops[0]) if mesh.topology.boundary_loops else np.array([0, 1])


def _sources(mesh):
    return np.array([0])


def _fixed_pair(mesh):
    """Two vertices, from the connectivity alone (concrete inside `jit` too): field interpolation's constraints."""
    return np.array([0, mesh.n_vertices // 2])


# Host-built objects per connectivity (topologies compare by content), made from the concrete mesh
# by a case's `inputs` and looked up inside `jit` by the traced mesh's (static) topology.
_INTRINSIC: dict = {}
_LARGE_STEPS: dict = {}


def _triangulation(mesh):
    if mesh.topology not in _INTRINSIC:
        _INTRINSIC[mesh.topology] = laplacian.intrinsic_delaunay(mesh)
    return _INTRINSIC[mesh.topology]


def _robust_values(mesh):
    """`_vertex_values`, after building the mesh's intrinsic triangulation (looked up by the call)."""
    _triangulation(mesh)
    return _vertex_values(mesh)


def _large_steps(mesh):
    if mesh.topology not in _LARGE_STEPS:
        _LARGE_STEPS[mesh.topology] = optim.large_steps(mesh, lambda_=10.0)
    return _LARGE_STEPS[mesh.topology]


def cases() -> list[Case]:
    """Every public problem-level entry point (ddgjax/*/__init__.py), with inputs a user would pass."""
    boundary_values = lambda mesh: (jnp.asarray(np.cos(np.arange(_boundary(mesh).size))),)
    return [
        # pde
        Case("pde.solve_poisson", lambda m, rho: pde.solve_poisson(m, rho), _vertex_values),
        Case(
            "pde.solve_poisson (Dirichlet boundary)",
            lambda m, rho: pde.solve_poisson(m, rho, fixed_vertices=_boundary(m)),
            _vertex_values,
            boundary=True,
        ),
        # The triangulation closed over: passed as a `jit` argument, solve_poisson cannot build its host plan.
        Case(
            "pde.solve_poisson (robust=T)",
            lambda m, rho: pde.solve_poisson(m, rho, robust=_INTRINSIC[m.topology]),
            _robust_values,
        ),
        Case(
            "pde.harmonic_interpolation",
            lambda m, values: pde.harmonic_interpolation(m, fixed_vertices=_boundary(m), fixed_values=values),
            boundary_values,
            boundary=True,
        ),
        Case("pde.dirichlet_energy", pde.dirichlet_energy, _vertex_values),
        Case("pde.poisson_energy", pde.poisson_energy, _two_vertex_values),
        Case("pde.screened_dirichlet_energy", lambda m, u: pde.screened_dirichlet_energy(m, u, 0.5), _vertex_values),
        Case(
            "pde.gradient_fitting_energy",
            pde.gradient_fitting_energy,
            lambda m: (*_vertex_values(m), jnp.asarray(_rng(m).standard_normal((m.n_faces, 3)))),
        ),
        Case("pde.hodge_decomposition", pde.hodge_decomposition, lambda m: (jnp.asarray(_rng(m).standard_normal(m.n_edges)),)),
        Case("pde.mean_curvature_flow (3 steps)", lambda m: pde.mean_curvature_flow(m, tau=1e-4, steps=3)),
        # spectral
        Case("spectral.eigenpairs (k=8)", lambda m: spectral.eigenpairs(m, 8)),
        # geodesics
        Case("geodesics.heat_distance", lambda m: geodesics.heat_distance(m, _sources(m))),
        # param
        Case("param.tutte_embedding", lambda m: param.tutte_embedding(m), boundary=True),
        Case("param.tutte_embedding (cotan)", lambda m: param.tutte_embedding(m, weights="cotan"), boundary=True),
        Case("param.harmonic_map", lambda m: param.harmonic_map(m), boundary=True),
        Case("param.lscm", lambda m: param.lscm(m), boundary=True),
        Case("param.spectral_conformal_map", lambda m: param.spectral_conformal_map(m), boundary=True),
        Case("param.boundary_first_flattening", lambda m: param.boundary_first_flattening(m), boundary=True),
        Case(
            "param.boundary_first_flattening (circle)",
            lambda m: param.boundary_first_flattening(m, shape="circle"),
            boundary=True,
        ),
        Case("param.conformal_energy_matrix", param.conformal_energy_matrix, boundary=True),
        Case("param.map_distortion", param.map_distortion, lambda m: (jnp.asarray(np.asarray(m.vertices)[:, :2]),)),
        # fields
        Case("fields.smoothest_field (n=4)", lambda m: fields.smoothest_field(m, n=4)),
        Case(
            "fields.smoothest_field (n=4, aligned)",
            lambda m, a: fields.smoothest_field(m, n=4, alignment=a),
            lambda m: (fields.principal_curvature_alignment(m, n=4),),
        ),
        Case(
            "fields.interpolate_field",
            lambda m, values: fields.interpolate_field(m, fixed_vertices=_fixed_pair(m), fixed_values=values),
            lambda m: (jnp.asarray([1.0 + 0j, 1j]),),
        ),
        Case("fields.principal_curvature_alignment", lambda m: fields.principal_curvature_alignment(m, n=4)),
        Case("fields.connection_laplacian", lambda m: fields.connection_laplacian(m, n=4)),
        Case("fields.connection_mass_matrix", fields.connection_mass_matrix),
        Case("fields.tangent_bases", fields.tangent_bases),
        Case("fields.edge_transport_angles", fields.edge_transport_angles),
        Case("fields.face_holonomies", fields.face_holonomies),
        Case(
            "fields.field_singularities",
            lambda m, f: fields.field_singularities(m, f, n=4),
            lambda m: (jnp.exp(1j * jnp.asarray(_rng(m).standard_normal(m.n_vertices))),),
        ),
        Case(
            "fields.field_to_vectors",
            lambda m, f: fields.field_to_vectors(m, f, n=4),
            lambda m: (jnp.exp(1j * jnp.asarray(_rng(m).standard_normal(m.n_vertices))),),
        ),
        # optim
        Case("optim.large_steps (build)", lambda m: optim.large_steps(m, lambda_=10.0), host=True),
        Case(
            "optim.LargeSteps.from_parameters",
            lambda m, ls, u: ls.from_parameters(u),
            lambda m: (_large_steps(m), _large_steps(m).to_parameters(m.vertices)),
        ),
        Case("optim.willmore_energy", optim.willmore_energy),
        Case("optim.edge_length_loss", optim.edge_length_loss),
        Case("optim.normal_consistency_loss", optim.normal_consistency_loss),
        Case("optim.laplacian_smoothing_loss (cotan)", lambda m: optim.laplacian_smoothing_loss(m, weights="cotan")),
        Case("optim.sample_points (5000)", lambda m, key: optim.sample_points(m, 5000, key=key), lambda m: (jax.random.key(0),)),
        # laplacian
        Case("laplacian.laplacian_and_mass", laplacian.laplacian_and_mass),
        Case(
            "laplacian.laplacian_and_mass (robust=T)",
            lambda m, t: laplacian.laplacian_and_mass(m, robust=t),
            lambda m: (_triangulation(m),),
        ),
        Case("laplacian.cotan_laplacian", laplacian.cotan_laplacian),
        Case("laplacian.mass_matrix", laplacian.mass_matrix),
        Case("laplacian.laplacian_apply", laplacian.laplacian_apply, _vertex_values),
        Case("laplacian.intrinsic_delaunay (build)", laplacian.intrinsic_delaunay, host=True),
        Case(
            "laplacian.intrinsic_delaunay_laplacian (T)",
            lambda m, t: laplacian.intrinsic_delaunay_laplacian(m, triangulation=t),
            lambda m: (_triangulation(m),),
        ),
        # mesh: curvature and geometry
        Case("mesh.vertex_angle_defects", meshes_.vertex_angle_defects),
        Case("mesh.vertex_mean_curvatures", meshes_.vertex_mean_curvatures),
        Case("mesh.vertex_mean_curvature_normals", meshes_.vertex_mean_curvature_normals),
        Case("mesh.vertex_gauss_curvature_normals", meshes_.vertex_gauss_curvature_normals),
        Case("mesh.vertex_pointwise_gaussian_curvatures", meshes_.vertex_pointwise_gaussian_curvatures),
        Case("mesh.vertex_pointwise_mean_curvatures", meshes_.vertex_pointwise_mean_curvatures),
        Case("mesh.vertex_principal_curvatures", meshes_.vertex_principal_curvatures),
        Case("mesh.total_mean_curvature", meshes_.total_mean_curvature),
        Case("mesh.vertex_normals", meshes_.vertex_normals),
        Case("mesh.vertex_dual_areas", meshes_.vertex_dual_areas),
        Case("mesh.edge_dihedral_angles", meshes_.edge_dihedral_angles),
        Case("mesh.check_mesh", meshes_.check_mesh, host=True),
        # dec
        Case("dec.d0 / d1", lambda m: (dec.d0(m), dec.d1(m))),
        Case("dec.hodge1", dec.hodge1),
        Case("dec.gradient_matrix", dec.gradient_matrix),
        Case("dec.gradient + divergence", lambda m, u: dec.divergence(m, dec.gradient(m, u)), _vertex_values),
        Case(
            "dec.hodge_laplacian1",
            lambda m, a: dec.hodge_laplacian1(m, a),
            lambda m: (jnp.asarray(_rng(m).standard_normal(m.n_edges)),),
        ),
    ]


def load(name):
    """A built-in icosphere (`icosphere(5)`) or a file in ../shared/meshes."""
    if name.startswith("icosphere("):
        return meshes_.icosphere(int(name[len("icosphere(") : -1]))
    return load_mesh(SHARED / name)


def section_eager(args) -> None:
    """The table: per mesh and function, eager and jitted ms and their ratio, flagged above the target."""
    only = [item.strip() for item in args.only.split(",")] if args.only else None
    flagged = []
    for mesh_name in args.meshes:
        mesh = load(mesh_name)
        has_boundary = bool(mesh.topology.boundary_loops)
        print(
            f"\n## {mesh_name}: {mesh.n_vertices} vertices, {mesh.n_faces} faces, {'with boundary' if has_boundary else 'closed'}\n"
        )
        print("| function | eager ms | jitted ms | eager / jitted |")
        print("|---|---|---|---|")
        for case in cases():
            if only and not any(item in case.name for item in only):
                continue
            if case.boundary and not has_boundary:
                continue
            inputs = (mesh, *case.inputs(mesh))
            calls = {"eager": (case.call, inputs)}
            if not case.host:
                calls["jitted"] = (jit(case.call), inputs)
            try:
                times, _ = timed_interleaved(warmed(calls), args.repeats, args.budget)
            except Exception as error:  # a function that cannot run here (report it, carry on)
                print(f"| {case.name} | failed: {type(error).__name__}: {str(error).splitlines()[0][:80]} | | |")
                continue
            if case.host:
                print(f"| {case.name} | {fmt(times['eager'], args.repeats)} | (host only) | - |")
                continue
            ratio = times["eager"][0] / times["jitted"][0]
            flag = f" **> {TARGET:g}x**" if ratio > TARGET else ""
            if flag:
                flagged.append(f"{mesh_name}: {case.name} {ratio:.2f}x")
            print(
                f"| {case.name} | {fmt(times['eager'], args.repeats)} | {fmt(times['jitted'], args.repeats)} | {ratio:.2f}x{flag} |"
            )
    print(f"\nover {TARGET:g}x: " + ("; ".join(flagged) if flagged else "none"))


SECTIONS = {"eager": section_eager}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default="eager")
    parser.add_argument("--meshes", default="spot.obj,hemisphere.obj,disk.obj,icosphere(5)", help="comma-separated")
    parser.add_argument("--only", default="", help="comma-separated substrings of function names to run")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--budget", type=float, default=2.0, help="seconds of runs per call, after which it stops repeating")
    run_sections(SECTIONS, parser.parse_args(argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
