"""Time to first result: each public entry point's first call in a fresh process, against the peer's.

Every case runs as a whole fresh Python process (as a notebook cell on a new mesh would), four ways:

- "empty": ddgjax's program store (`ddgjax._program_store`) in a new, empty directory;
- "other size": the store warmed by one earlier process that ran the same call on a mesh of a
  different size (`--other`, default `icosphere(4)`: 2,562 vertices against spot's 2,930);
- "same size": the store warmed by an earlier process on this very mesh;
- the peer's own first call in a fresh process (libigl, potpourri3d, SciPy, robust_laplacian, pyFM).

Each ddgjax figure is split into `import jax`, `import ddgjax` and the first call; the first call into
JAX's tracing, lowering and XLA compiling (`jax.monitoring`'s compile events), ddgjax's store reads,
the second call's time (the running) and the rest (host work: plans, factorisations, first imports
of subpackages). Peer figures are the whole process after its imports, and with them.

Run: `python benchmarks/first_call.py [--mesh PATH] [--other MESH] [--only NAMES] [--rounds N]`
(`--mesh "icosphere(6)"` for the 40k row; the full run on spot is ~15 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile

SHARED_MESHES = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "meshes"

# What every ddgjax process runs before its case: imports timed, the mesh loaded, JAX's compile events
# and the program store's reads summed. `MESH` is a path or a `ddgjax.mesh` shape like "icosphere(4)".
DDGJAX_PRELUDE = """
import time
start = time.perf_counter()
import json, sys
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
import numpy as np
after_jax = time.perf_counter()
import ddgjax
from ddgjax import _program_store
after_ddgjax = time.perf_counter()
phases = {"trace": 0.0, "lower": 0.0, "compile": 0.0, "store": 0.0}
EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace", "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
          "/jax/core/compile/backend_compile_duration": "compile"}
def listen(event, seconds, **_):
    if event in EVENTS:
        phases[EVENTS[event]] += seconds
jax.monitoring.register_event_duration_secs_listener(listen)
_load = _program_store.load
def timed_load(*args):
    begin = time.perf_counter()
    try:
        return _load(*args)
    finally:
        phases["store"] += time.perf_counter() - begin
_program_store.load = timed_load
def make_mesh(spec):
    return eval("ddgjax.mesh." + spec) if "(" in spec else ddgjax.io.load_mesh(spec)
mesh = make_mesh(sys.argv[1])
V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
ready = time.perf_counter()
"""

DDGJAX_EPILOGUE = """
begin = time.perf_counter()
jax.block_until_ready(run())
first = time.perf_counter() - begin
counted = dict(phases)
begin = time.perf_counter()
jax.block_until_ready(run())
second = time.perf_counter() - begin
print(json.dumps({"import_jax": after_jax - start, "import_ddgjax": after_ddgjax - after_jax, "first": first,
                  "second": second, **counted}))
"""

PEER_PRELUDE = """
import time
start = time.perf_counter()
import json, sys
import numpy as np, scipy.sparse as sp, scipy.sparse.linalg as sla
import igl, potpourri3d as pp3d, robust_laplacian
def make_mesh(spec):
    if "(" in spec:  # the same shapes as ddgjax's, made by ddgjax in a separate step (`peer_arrays`)
        data = np.load(sys.argv[2])
        return data["V"], data["F"]
    return igl.read_triangle_mesh(spec)
V, F = make_mesh(sys.argv[1])
V, F = np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int64)
ready = time.perf_counter()
"""

PEER_EPILOGUE = """
begin = time.perf_counter()
run()
first = time.perf_counter() - begin
print(json.dumps({"first": first, "whole": time.perf_counter() - start}))
"""

NOTEBOOK = """
def run():
    L, M = ddgjax.laplacian.cotan_laplacian(mesh), ddgjax.laplacian.mass_matrix(mesh)
    d = ddgjax.geodesics.heat_distance(mesh, [0])
    pairs = ddgjax.spectral.eigenpairs(mesh, 20)
    rho = jnp.asarray(V[:, 2] - V[:, 2].mean())
    u = ddgjax.pde.solve_poisson(mesh, rho * ddgjax.laplacian.mass_matrix(mesh).diagonal(), fixed_vertices=[0], fixed_values=[0.0])
    return L.values, d, pairs.values, u, ddgjax.geodesics.log_map(mesh, 0)
"""

NOTEBOOK_PEER = """
def run():
    L, M = -igl.cotmatrix(V, F), igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI)
    d = pp3d.MeshHeatMethodDistanceSolver(V, F).compute_distance(0)
    values, vectors = sla.eigsh(L, 20, M, sigma=-1e-8)
    rho = M @ (V[:, 2] - V[:, 2].mean())
    free = np.arange(1, len(V))
    u = sla.spsolve(L[free][:, free].tocsc(), rho[free])
    return pp3d.MeshVectorHeatSolver(V, F).compute_log_map(0)
"""

# An 8-edge path from vertex 0, always to the neighbour of largest x: the same curve for both libraries.
EDGE_PATH = """
edges = np.unique(np.sort(np.vstack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
path = [0]
for _ in range(8):
    ends = np.concatenate([edges[edges[:, 0] == path[-1], 1], edges[edges[:, 1] == path[-1], 0]])
    path.append(max((int(v) for v in ends if v not in path), key=lambda v: V[v, 0]))
"""

# name: (ddgjax's `run`, the peer's `run` or None, a mesh of its own or None). Bodies use `mesh`, `V`, `F`.
CASES: dict[str, tuple[str, str | None, dict | None]] = {
    "notebook job (L, heat, 20 eigenpairs, Poisson, log map)": (NOTEBOOK, NOTEBOOK_PEER, None),
    "cotan_laplacian": (
        "def run(): return ddgjax.laplacian.cotan_laplacian(mesh).values",
        "def run(): return igl.cotmatrix(V, F)",
        None,
    ),
    "mass_matrix": (
        "def run(): return ddgjax.laplacian.mass_matrix(mesh).values",
        "def run(): return igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI)",
        None,
    ),
    "vertex_principal_curvatures": (
        "def run(): return ddgjax.mesh.vertex_principal_curvatures(mesh)",
        "def run(): return igl.principal_curvature(V, F)",
        None,
    ),
    "heat_distance": (
        "def run(): return ddgjax.geodesics.heat_distance(mesh, [0])",
        "def run(): return pp3d.MeshHeatMethodDistanceSolver(V, F).compute_distance(0)",
        None,
    ),
    "eigenpairs(k=20)": (
        "def run(): return ddgjax.spectral.eigenpairs(mesh, 20).values",
        "def run(): return sla.eigsh(-igl.cotmatrix(V, F), 20, igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI), sigma=-1e-8)",
        None,
    ),
    "solve_poisson": (
        "def run(): return ddgjax.pde.solve_poisson(mesh, jnp.asarray(V[:, 2] - V[:, 2].mean()), fixed_vertices=[0], fixed_values=[0.0])",
        "def run():\n    L = -igl.cotmatrix(V, F); f = np.arange(1, len(V))\n    return sla.spsolve(L[f][:, f].tocsc(), (V[:, 2] - V[:, 2].mean())[f])",
        None,
    ),
    "harmonic_interpolation (graph)": (
        "edges = np.asarray(mesh.topology.edges)\n"
        "def run(): return ddgjax.graph.harmonic_interpolation(edges, fixed_vertices=[0, 1], fixed_values=[0.0, 1.0], n_vertices=len(V))",
        "def run(): return igl.harmonic(V, F, np.array([0, 1]), np.array([[0.0], [1.0]]), 1)",
        None,
    ),
    "log_map": (
        "def run(): return ddgjax.geodesics.log_map(mesh, 0)",
        "def run(): return pp3d.MeshVectorHeatSolver(V, F).compute_log_map(0)",
        None,
    ),
    "parallel_transport": (
        "def run(): return ddgjax.geodesics.parallel_transport(mesh, 0, jnp.asarray([1.0, 0.0, 0.0]))",
        "def run(): return pp3d.MeshVectorHeatSolver(V, F).transport_tangent_vector(0, [1.0, 0.0])",
        None,
    ),
    "signed_heat_distance": (
        EDGE_PATH + "def run(): return ddgjax.geodesics.signed_heat_distance(mesh, [path])",
        EDGE_PATH + "def run(): return pp3d.MeshSignedHeatSolver(V, F).compute_distance([[(v, []) for v in path]])",
        None,
    ),
    "smoothest_field (n=4)": ("def run(): return ddgjax.fields.smoothest_field(mesh, n=4)", None, None),
    "boundary_first_flattening": (
        "def run(): return ddgjax.param.boundary_first_flattening(mesh)",
        "def run():\n    b = igl.boundary_loop(F); bc = igl.map_vertices_to_circle(V, b)\n    return igl.harmonic(V, F, b, bc, 1)",
        {"mesh": "disk(31)", "other": "disk(28)", "large": "disk(116)"},
    ),
    "biharmonic_deformation": (
        "fixed = np.arange(0, len(V), max(1, len(V) // 20))\n"
        "def run(): return ddgjax.deform.biharmonic_deformation(mesh, fixed_vertices=fixed, fixed_values=V[fixed] + 0.1)",
        "fixed = np.arange(0, len(V), max(1, len(V) // 20))\ndef run(): return igl.harmonic(V, F, fixed, V[fixed] + 0.1, 2)",
        None,
    ),
    "arap": (
        "fixed = np.arange(0, len(V), max(1, len(V) // 20))\n"
        "def run(): return ddgjax.deform.arap(mesh, fixed_vertices=fixed, fixed_values=V[fixed] + 0.1)",
        "fixed = np.arange(0, len(V), max(1, len(V) // 20))\n"
        # libigl's steps until one moves no vertex by more than ddgjax's default rtol (1e-8) of the diagonal.
        "def run():\n    data = igl.ARAPData(); data.energy = igl.ARAP_ENERGY_TYPE_SPOKES; data.max_iter = 1\n"
        "    igl.arap_precomputation(V, F, 3, fixed, data)\n    U, scale = V.copy(), np.linalg.norm(V.max(0) - V.min(0))\n"
        "    for _ in range(1000):\n        new = igl.arap_solve(V[fixed] + 0.1, data, U)\n"
        "        if np.abs(new - U).max() <= 1e-8 * scale: return new\n        U = new\n    return U",
        None,
    ),
    "match_shapes (k=30, no refinement)": (
        "target = mesh.with_vertices(mesh.vertices * jnp.asarray([1.0, 1.1, 0.9]))\n"
        "def run(): return ddgjax.matching.match_shapes(mesh, target, k=30, refine=None)",
        None,
        None,
    ),
    "euler_flow (k=64, 10 steps)": (
        "def run(): return ddgjax.fluids.euler_flow(mesh, jnp.asarray(V[:, 2]), tau=0.01, steps=10)",
        None,
        None,
    ),
    "point_cloud_laplacian": (
        "def run(): return ddgjax.pointcloud.point_cloud_laplacian(V)",
        "def run(): return robust_laplacian.point_cloud_laplacian(V)",
        None,
    ),
    "curve_shortening_flow (1,000 steps)": (
        "curve = ddgjax.curves.flower(len(V) // 10)\n"
        "def run(): return ddgjax.curves.curve_shortening_flow(curve, kind='B', tau=1e-5, steps=1000)",
        None,
        None,
    ),
    "diffusion_operators (k=64)": (
        "import tempfile\ndef run(): return ddgjax.learn.diffusion_operators(mesh, 64, cache_dir=tempfile.mkdtemp())",
        "def run():\n    L, M = robust_laplacian.mesh_laplacian(V, F)\n    return sla.eigsh(L, 64, M, sigma=-1e-8)",
        None,
    ),
}


def run_process(script: str, arguments: list[str], env: dict) -> dict:
    result = subprocess.run([sys.executable, "-c", script, *arguments], env=env, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(result.stderr[-3000:])
    return json.loads(result.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default=str(SHARED_MESHES / "spot.obj"))
    parser.add_argument("--other", default="icosphere(4)", help="the mesh of a different size that warms the store")
    parser.add_argument("--only", default="", help="comma-separated case names (prefixes)")
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--large", action="store_true", help="cases with a mesh of their own take their large one")
    args = parser.parse_args(argv)
    env = {key: value for key, value in os.environ.items() if key not in ("DDGJAX_COMPILATION_CACHE", "DDGJAX_CACHE_DIR")}
    chosen = [name for name in CASES if not args.only or any(name.startswith(p) for p in args.only.split(","))]
    print(f"# {args.mesh} (other size: {args.other}); seconds; {args.rounds} round(s), min")
    header = "| case | empty | other size | same size | of which: trace / lower / compile / store / run | peer | peer, whole process | same size / peer |"
    print(header)
    print("|---" * 8 + "|")
    for name in chosen:
        body, peer_body, meshes = CASES[name]
        target = args.mesh if meshes is None else meshes["large" if args.large else "mesh"]
        other = args.other if meshes is None else meshes["other"]
        figures: dict[str, list[dict]] = {"empty": [], "other": [], "same": [], "peer": []}
        with tempfile.TemporaryDirectory() as scratch:
            arrays = pathlib.Path(scratch) / "mesh.npz"
            # The target's arrays, for a peer given a ddgjax shape rather than a file.
            run_process(
                DDGJAX_PRELUDE + "np.savez(sys.argv[2], V=V, F=F)\nprint('{}')\n",
                [target, str(arrays)],
                {**env, "DDGJAX_COMPILATION_CACHE": "0"},
            )
            script = DDGJAX_PRELUDE + body + DDGJAX_EPILOGUE
            for _ in range(args.rounds):
                with tempfile.TemporaryDirectory() as store:
                    figures["empty"].append(run_process(script, [target], {**env, "DDGJAX_CACHE_DIR": store}))
                with tempfile.TemporaryDirectory() as store:
                    run_process(script, [other], {**env, "DDGJAX_CACHE_DIR": store})
                    figures["other"].append(run_process(script, [target], {**env, "DDGJAX_CACHE_DIR": store}))
                    figures["same"].append(run_process(script, [target], {**env, "DDGJAX_CACHE_DIR": store}))
                if peer_body is not None:
                    figures["peer"].append(run_process(PEER_PRELUDE + peer_body + PEER_EPILOGUE, [target, str(arrays)], env))
        best = {kind: min(runs, key=lambda r: r["first"]) for kind, runs in figures.items() if runs}
        same = best["same"]
        split = " / ".join(f"{same[p]:.2f}" for p in ("trace", "lower", "compile", "store")) + f" / {same['second']:.2f}"
        peer = best.get("peer")
        peer_cells = f"{peer['first']:.2f} | {peer['whole']:.2f} | {same['first'] / peer['first']:.1f}x" if peer else "- | - | -"
        print(
            f"| {name} | {best['empty']['first']:.2f} | {best['other']['first']:.2f} | {same['first']:.2f} | {split} | {peer_cells} |",
            flush=True,
        )
    imports = best["same"]
    print(f"# import jax {imports['import_jax']:.2f} s, import ddgjax {imports['import_ddgjax']:.2f} s (last process)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
