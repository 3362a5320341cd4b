"""Start-up: the whole `ddgjax info MESH` command, cold and warm compilation cache, against libigl.

Each round runs, interleaved, as fresh processes: `ddgjax info` with an empty compilation cache
(cold), the same command again (warm: every program read from JAX's persistent cache), the same
report computed with libigl (`LIBIGL_REPORT`), and `import jax` alone. Prints median (min) wall
clock in seconds. Run: `python benchmarks/startup.py [MESH] [--rounds N]`.
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
    info = [sys.executable, "-m", "ddgjax.cli", "info", args.mesh]
    times: dict[str, list[float]] = {"ddgjax info, cold": [], "ddgjax info, warm": [], "libigl report": [], "import jax": []}
    for _ in range(args.rounds):
        with tempfile.TemporaryDirectory() as cache:
            cached = {**env, "XDG_CACHE_HOME": cache}
            times["ddgjax info, cold"].append(wall_clock(info, cached))
            times["ddgjax info, warm"].append(wall_clock(info, cached))
        times["libigl report"].append(wall_clock([sys.executable, "-c", LIBIGL_REPORT, args.mesh], env))
        times["import jax"].append(wall_clock([sys.executable, "-c", "import jax, jax.numpy"], env))
    print(f"# {args.mesh}, {args.rounds} rounds: median (min) wall clock, s")
    for name, values in times.items():
        print(f"  {name:<20s} {np.median(values):.2f} ({min(values):.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
