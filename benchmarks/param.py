"""Surface parametrisation: ddgjax side by side with libigl, one process, same meshes.

One section, **maps**, on the disk-topology meshes of `../shared/meshes` and a ~100k-face disk
(`disk(130)`: 101,400 faces, its interior jittered so the cotan weights vary):

- Tutte (uniform weights, circle): ddgjax `tutte_embedding` (jitted on the vertices). libigl has no
  uniform-weight Tutte in its Python bindings; its peer is the cotan `harmonic` row below.
- harmonic map (cotan weights, circle by arc length): ddgjax `harmonic_map` against
  `igl.harmonic(V, F, b, igl.map_vertices_to_circle(V, b), 1)` (boundary loop and placement included).
- LSCM (two pins): ddgjax `lscm` against `igl.lscm(V, F, b, bc)` with the same pins and positions.
- also ddgjax's BFF (u = 0) and the value and gradient of an LSCM distortion energy (no libigl peer).

Target: each ddgjax map no slower than its libigl peer. Times: min / median ms over interleaved
repeats (`benchmarks/solve.py`'s `timed_interleaved`); compile time separately.
Run: `python benchmarks/param.py [--meshes NAMES] [--repeats 5]`.
"""

from __future__ import annotations

import pathlib
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, jit, mesh_sections_parser, optional, run_sections, timed_interleaved, warmed  # noqa: E402

from ddgjax.io import load_mesh  # noqa: E402
from ddgjax.mesh import disk  # noqa: E402
from ddgjax.param import boundary_first_flattening, harmonic_map, lscm, map_distortion, tutte_embedding  # noqa: E402

igl = optional("igl")
SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "meshes"
DEFAULT_MESHES = "small_disk.obj,hemisphere.obj,hexagon.obj,disk.obj,camelhead.off,disk(130)"


def meshes(names):
    """`{name: mesh}`: `disk(n)` (interior jittered by a fifth of the ring spacing) or files in ../shared/meshes."""
    result = {}
    for name in names:
        if name.startswith("disk("):
            n = int(name[len("disk(") : -1])
            mesh = disk(n)
            V = np.asarray(mesh.vertices).copy()
            interior = np.setdiff1d(np.arange(V.shape[0]), mesh.topology.boundary_vertices)
            V[interior, :2] += 0.2 / n * np.random.default_rng(0).uniform(-1, 1, (interior.size, 2))
            result[name] = mesh.with_vertices(V)
        else:
            result[name] = load_mesh(SHARED / name)
    return result


def section_maps(args):
    print("\n# parametrisation of disks: ddgjax (jitted on the vertex positions) and libigl")
    for name, mesh in meshes(args.meshes).items():
        _maps_on(name, mesh, args)


def _maps_on(name, mesh, args):
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
    loop = np.asarray(mesh.topology.boundary_loops[0])
    pins = np.array([loop[0], loop[loop.size // 2]])
    positions = np.array([[0.0, 0.0], [1.0, 0.0]])

    def lscm_energy(vertices):
        moved = mesh.with_vertices(vertices)
        return map_distortion(moved, lscm(moved, fixed_vertices=pins, fixed_values=positions)).total_conformal_energy

    ours = {
        "ddgjax tutte_embedding (uniform)": jit(lambda v: tutte_embedding(mesh.with_vertices(v))),
        "ddgjax harmonic_map": jit(lambda v: harmonic_map(mesh.with_vertices(v))),
        "ddgjax lscm": jit(lambda v: lscm(mesh.with_vertices(v), fixed_vertices=pins, fixed_values=positions)),
        "ddgjax boundary_first_flattening": jit(lambda v: boundary_first_flattening(mesh.with_vertices(v))),
        "ddgjax lscm energy value_and_grad": jit(jax.value_and_grad(lscm_energy)),
    }
    compile_ms = {}
    for row, fn in ours.items():
        start = time.perf_counter()
        fn.lower(mesh.vertices).compile()
        compile_ms[row] = 1e3 * (time.perf_counter() - start)
    calls = {row: (fn, (mesh.vertices,)) for row, fn in ours.items()}
    peers = {"ddgjax harmonic_map": "libigl harmonic (+ boundary_loop, circle)", "ddgjax lscm": "libigl lscm"}
    if igl is not None:

        def igl_harmonic():
            b = igl.boundary_loop(F)
            return igl.harmonic(V, F, b, igl.map_vertices_to_circle(V, b), 1)

        calls[peers["ddgjax harmonic_map"]] = (igl_harmonic, ())
        calls[peers["ddgjax lscm"]] = (lambda: igl.lscm(V, F, pins, positions)[0], ())
    times, results = timed_interleaved(warmed(calls), args.repeats, args.budget)
    flips = int(map_distortion(mesh, results["ddgjax tutte_embedding (uniform)"]).n_flipped)
    print(
        f"\n## {name}: nv = {mesh.n_vertices}, nf = {mesh.n_faces}  (min / median ms; ratio to the libigl peer; Tutte flips: {flips})"
    )
    for row, t in times.items():
        peer = peers.get(row)
        ratio = f"{t[0] / times[peer][0]:7.2f}x" if peer in times else " " * 8
        compiled = f"compile {compile_ms[row]:8.1f} ms" if row in compile_ms else ""
        print(f"  {row:46s} {fmt(t, args.repeats):>22s} {ratio}  {compiled}")
    if igl is not None:
        difference = np.abs(np.asarray(results["ddgjax lscm"]) - results["libigl lscm"]).max()
        print(f"  max |ddgjax lscm - libigl lscm| = {difference:.1e}")


SECTIONS = {"maps": section_maps}


def main(argv=None) -> int:
    parser = mesh_sections_parser(__doc__.splitlines()[0], SECTIONS, DEFAULT_MESHES, budget=10.0)
    run_sections(SECTIONS, parser.parse_args(argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
