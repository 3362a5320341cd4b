"""Operators for learning: DiffusionNet's per-shape precompute, ddgjax against robust_laplacian + SciPy.

What every training shape of a diffusion network needs once (Sharp et al. 2022, `get_operators`):
the lumped mass, the `k` smallest eigenpairs of `L phi = lambda M phi` (`k = 128`, DiffusionNet's
default, and `k = 32`), the vertex tangent frames and the spatial gradient operator. Contenders:

- **ddgjax**: `ddgjax.learn.diffusion_operators(mesh, k, mass="barycentric", robust=True)` (the intrinsic
  Delaunay operators, mollified, with robust_laplacian's barycentric mass; ARPACK shift-invert on the
  host; the gradient weights a compiled kernel).
- **reference**: what DiffusionNet does, in its libraries: `robust_laplacian.mesh_laplacian(V, F,
  mollify_factor=1e-5)`, `scipy.sparse.linalg.eigsh(L, k, M, sigma=-1e-8)` (shift-invert Lanczos), and
  the gradient as a vectorised NumPy per-vertex least-squares fit of the one-ring in the tangent plane,
  stored as a sparse complex matrix (DiffusionNet's `build_grad` loops over vertices in Python; this
  one does not, so it is the faster reference).

Meshes: the shared meshes of about 5k to 50k vertices (`--meshes`) and a built-in icosphere (level 5,
10,242 vertices). ddgjax's first call on a mesh compiles its kernels for that size: it is printed
apart (`first s`); then calls run in rounds, one per contender per round, and min and median seconds
are printed with the ratios of medians and of minima (ddgjax / reference; below 1 ddgjax is faster; on a
shared machine the minima are the steadier). The eigenvalues of both are compared (largest relative
difference). Where it is large the reference is the one that is wrong: on the icosphere, whose
eigenvalues come in symmetric clusters, shift-invert `eigsh` with SciPy's random start returns a set
that misses cluster members at the cut (level 4, k = 32: 3e-3 from dense `scipy.linalg.eigh`, ddgjax 3e-13).

Run: `python benchmarks/learning.py` (about 10 minutes on 2 cores); `--k 32,128`, `--repeats 3`,
`--meshes disk.obj,beetle.off`; `--profile` splits ddgjax's time into its parts on each mesh
(intrinsic Delaunay `L` and `M`, eigensolve, gradient fit).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import platform
import statistics
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import robust_laplacian  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

from ddgjax.io import load_mesh  # noqa: E402
from ddgjax.laplacian import laplacian_and_mass  # noqa: E402
from ddgjax.learn import diffusion_operators  # noqa: E402
from ddgjax.learn._gradient import gradient_frames_and_weights, neighbor_table  # noqa: E402
from ddgjax.mesh import icosphere  # noqa: E402
from ddgjax.spectral import smallest_eigenpairs  # noqa: E402

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "meshes"
MESHES = ("disk.obj", "kitten.obj", "camelhead.off", "beetle.off", "armadillo.obj", "nefertiti.obj")


# --- the reference: robust_laplacian + SciPy + NumPy ------------------------------------------------


def numpy_gradient(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
    """`(frames, G)`: per-vertex frames `(nv, 3, 3)` and the complex `(nv, nv)` gradient `G u = g_x + i g_y`.

    The one-ring least-squares fit (`ddgjax.learn._gradient` docstring), vectorised over directed edges.
    """
    nv = V.shape[0]
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    normals = np.zeros((nv, 3))
    for c in range(3):
        np.add.at(normals, F[:, c], fn)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    adjacency = sp.coo_matrix((np.ones(3 * F.shape[0]), (F.ravel(), np.roll(F, -1, axis=1).ravel())), shape=(nv, nv))
    adjacency = ((adjacency + adjacency.T) > 0).tocsr()
    rows = np.repeat(np.arange(nv), np.diff(adjacency.indptr))
    cols = adjacency.indices
    edges = V[cols] - V[rows]
    first = edges[adjacency.indptr[:-1].clip(max=cols.size - 1)]
    e1 = first - np.sum(first * normals, axis=1, keepdims=True) * normals
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-300)
    e2 = np.cross(normals, e1)
    local = np.stack([np.sum(edges * e1[rows], axis=1), np.sum(edges * e2[rows], axis=1)], axis=1)
    gram = np.zeros((nv, 2, 2))
    np.add.at(gram, rows, local[:, :, None] * local[:, None, :])
    gram += 1e-12 * np.trace(gram, axis1=1, axis2=2)[:, None, None] * np.eye(2)
    weights = np.einsum("eab,eb->ea", np.linalg.inv(gram)[rows], local)
    w = weights[:, 0] + 1j * weights[:, 1]
    G = sp.csr_matrix((w, (rows, cols)), shape=(nv, nv)) - sp.diags(
        np.bincount(rows, weights=w.real, minlength=nv) + 1j * np.bincount(rows, weights=w.imag, minlength=nv)
    )
    return np.stack([e1, e2, normals], axis=1), G.tocsr()


def reference(V: np.ndarray, F: np.ndarray, k: int):
    """DiffusionNet's precompute with its libraries: `(values, vectors, mass, frames, G)`."""
    L, M = robust_laplacian.mesh_laplacian(V, F, mollify_factor=1e-5)
    values, vectors = spla.eigsh(L.tocsc(), k, M.tocsc(), sigma=-1e-8)
    frames, G = numpy_gradient(V, F)
    return values, vectors, M.diagonal(), frames, G


def ours(mesh, k: int):
    return jax.block_until_ready(diffusion_operators(mesh, k, mass="barycentric", robust=True))


# --- measuring ---------------------------------------------------------------------------------------


def timed(fn):
    start = time.perf_counter()
    value = fn()
    return time.perf_counter() - start, value


def profile(mesh, k: int) -> dict:
    """Seconds of ddgjax's parts on a warm mesh: intrinsic Delaunay `L, M`; eigensolve; gradient table and fit."""
    parts = {}
    parts["L, M (intrinsic Delaunay)"], (L, M) = timed(
        lambda: jax.block_until_ready(laplacian_and_mass(mesh, mass="barycentric", robust=True))
    )
    parts["eigensolve"], _ = timed(lambda: jax.block_until_ready(smallest_eigenpairs(L, M, k)))
    parts["gradient fit"], _ = timed(
        lambda: jax.block_until_ready(gradient_frames_and_weights(mesh, jnp.asarray(neighbor_table(mesh.topology))))
    )
    return parts


def run(name: str, mesh, k: int, repeats: int, show_profile: bool) -> dict:
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces).astype(np.int64)
    first, operators = timed(lambda: ours(mesh, k))
    samples = {"ddgjax": [], "reference": []}
    for _ in range(repeats):
        seconds, operators = timed(lambda: ours(mesh, k))
        samples["ddgjax"].append(seconds)
        seconds, expected = timed(lambda: reference(V, F, k))
        samples["reference"].append(seconds)
    values = np.sort(expected[0])
    difference = np.max(np.abs(np.asarray(operators.values)[1:] - values[1:]) / values[1:])
    row = {
        "mesh": name,
        "nv": mesh.n_vertices,
        "k": k,
        "first": first,
        **{f"{who} min": min(s) for who, s in samples.items()},
        **{f"{who} median": statistics.median(s) for who, s in samples.items()},
        "eig rel diff": difference,
    }
    row["ratio"] = row["ddgjax median"] / row["reference median"]
    row["ratio of min"] = row["ddgjax min"] / row["reference min"]
    print(
        f"| {name} | {row['nv']:,} | {k} | {first:.2f} | {row['ddgjax min']:.2f} / {row['ddgjax median']:.2f} | "
        f"{row['reference min']:.2f} / {row['reference median']:.2f} | {row['ratio']:.2f} | {row['ratio of min']:.2f} | {difference:.1e} |",
        flush=True,
    )
    if show_profile:
        parts = profile(mesh, k)
        print("    ddgjax parts: " + ", ".join(f"{part} {seconds:.2f} s" for part, seconds in parts.items()), flush=True)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--k", default="32,128", help="numbers of eigenpairs, comma separated")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--meshes", default=",".join(MESHES), help="shared meshes, comma separated (icosphere always)")
    parser.add_argument("--profile", action="store_true", help="split ddgjax's time into its parts")
    args = parser.parse_args()
    print(
        f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__} on {jax.default_backend()}"
    )
    meshes = [(name, load_mesh(SHARED / name)) for name in args.meshes.split(",") if name]
    meshes.append(("icosphere(5)", icosphere(5)))
    print(
        "| mesh | nv | k | ddgjax first s | ddgjax min / median s | reference min / median s | ratio (medians) | ratio (min) | eig rel diff |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for k in map(int, args.k.split(",")):
        for name, mesh in meshes:
            run(name, mesh, k, args.repeats, args.profile)


if __name__ == "__main__":
    main()
