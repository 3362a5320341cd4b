"""Start-up: fresh processes doing a small job, ddgjax against libigl + SciPy, cold and warm compilation cache.

Two jobs, each as a whole fresh process:

- "solve once": load a mesh, build the cotan Laplacian `L`, the mass matrix `M` and the angle
  defects `K`, and solve `(M + 0.01 L) u = K` once (`SOLVE_DDGJAX` against `SOLVE_LIBIGL`, libigl's
  `cotmatrix` / `massmatrix` / `gaussian_curvature` and SciPy's `spsolve`). ddgjax runs it with
  JAX's persistent compilation cache in a fresh directory: "cold" is the first run, "warm" the next
  (every program read from the cache).
- "ddgjax info": the whole `ddgjax info MESH` command against the same report computed with libigl
  (`LIBIGL_REPORT`).

Plus `import jax` alone and `import jax; import ddgjax` (the lazy package import). Rounds are
interleaved; prints median (min) wall clock in seconds and the ratios the targets are stated in.
Run: `python benchmarks/startup.py [MESH] [--rounds N]`.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import numpy as np

DEFAULT_MESH = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "meshes" / "spot.obj"

# The same report as `ddgjax info`: topology, area, volume, Gauss-Bonnet, pointwise curvature statistics.
LIBIGL_REPORT = """
import sys, igl, numpy as np
V, F = igl.read_triangle_mesh(sys.argv[1])
E, chi, parts, loops = igl.edges(F), igl.euler_characteristic(F), igl.facet_components(F)[0], igl.boundary_loop_all(F)
manifold = igl.is_edge_manifold(F)[0] and igl.is_vertex_manifold(F).all()
area, volume = igl.doublearea(V, F).sum() / 2, np.einsum("ij,ij->", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])) / 6
defects, A = igl.gaussian_curvature(V, F), igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI).diagonal()
HN = -(igl.cotmatrix(V, F) @ V) / A[:, None] / 2
H = np.linalg.norm(HN, axis=1) * np.sign(np.einsum("ij,ij->i", HN, igl.per_vertex_normals(V, F)))
K = defects / A; root = np.sqrt(np.maximum(H * H - K, 0))
print(len(V), len(F), len(E), chi, parts, manifold, len(loops), area, volume, defects.sum() - 2 * np.pi * chi)
for x in (K, H, H + root, H - root): print(x.min(), np.median(x), x.max())
"""


SOLVE_DDGJAX = """
import sys, jax
jax.config.update("jax_enable_x64", True)
import ddgjax
mesh = ddgjax.io.load_mesh(sys.argv[1])
L, M = ddgjax.laplacian.laplacian_and_mass(mesh)
K = ddgjax.mesh.vertex_angle_defects(mesh)
u = ddgjax.solve.linear_solve(M + 0.01 * L, K).value
print(float(u.sum()))
"""

SOLVE_LIBIGL = """
import sys, igl, numpy as np, scipy.sparse.linalg as sla
V, F = igl.read_triangle_mesh(sys.argv[1])
L, M = -igl.cotmatrix(V, F), igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI)
K = igl.gaussian_curvature(V, F)
u = sla.spsolve((M + 0.01 * L).tocsc(), K)
print(float(u.sum()))
"""

# JAX's persistent cache for a plain script (the CLI sets the same for itself): every program kept.
CACHE_ENV = {
    "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
    "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "-1",
}


def wall_clock(command: list[str], env: dict) -> float:
    start = time.perf_counter()
    subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", nargs="?", default=str(DEFAULT_MESH))
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args(argv)
    env = {key: value for key, value in os.environ.items() if key not in ("DDGJAX_COMPILATION_CACHE", "PYTHONDONTWRITEBYTECODE")}
    python = sys.executable
    times: dict[str, list[float]] = {
        name: []
        for name in (
            "solve once, ddgjax cold",
            "solve once, ddgjax warm",
            "solve once, libigl + SciPy",
            "ddgjax info, cold",
            "ddgjax info, warm",
            "libigl report",
            "import jax",
            "import jax, ddgjax",
        )
    }
    for _ in range(args.rounds):
        with tempfile.TemporaryDirectory() as cache:
            cached = {**env, **CACHE_ENV, "JAX_COMPILATION_CACHE_DIR": cache}
            times["solve once, ddgjax cold"].append(wall_clock([python, "-c", SOLVE_DDGJAX, args.mesh], cached))
            times["solve once, ddgjax warm"].append(wall_clock([python, "-c", SOLVE_DDGJAX, args.mesh], cached))
        times["solve once, libigl + SciPy"].append(wall_clock([python, "-c", SOLVE_LIBIGL, args.mesh], env))
        with tempfile.TemporaryDirectory() as cache:
            cached = {**env, "XDG_CACHE_HOME": cache}
            info = [python, "-m", "ddgjax.cli", "info", args.mesh]
            times["ddgjax info, cold"].append(wall_clock(info, cached))
            times["ddgjax info, warm"].append(wall_clock(info, cached))
        times["libigl report"].append(wall_clock([python, "-c", LIBIGL_REPORT, args.mesh], env))
        times["import jax"].append(wall_clock([python, "-c", "import jax, jax.numpy"], env))
        times["import jax, ddgjax"].append(wall_clock([python, "-c", "import jax, jax.numpy, ddgjax"], env))
    median = {name: float(np.median(values)) for name, values in times.items()}
    print(f"# {args.mesh}, {args.rounds} rounds: median (min) wall clock, s")
    for name, values in times.items():
        print(f"  {name:<28s} {median[name]:.2f} ({min(values):.2f})")
    print(
        f"  solve once, warm / libigl + SciPy: {median['solve once, ddgjax warm'] / median['solve once, libigl + SciPy']:.2f}x (target 3x)"
    )
    print(f"  ddgjax info, warm / libigl: {median['ddgjax info, warm'] / median['libigl report']:.2f}x")
    print(f"  import ddgjax beyond JAX: {median['import jax, ddgjax'] - median['import jax']:.3f} s (target 0.35 s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
