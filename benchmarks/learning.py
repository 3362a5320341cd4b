"""Learning on meshes: DiffusionNet's per-shape precompute against robust_laplacian + SciPy; batched Laplacian throughput.

Three sections (`--sections precompute,dataset,batch`, all by default):

**precompute** (per mesh, warm):

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

**dataset**: what preprocessing a dataset costs, where every mesh has a size of its own:
`--dataset-meshes` random convex meshes (trimesh's hull of points on a sphere) of distinct sizes
from 1,000 to 8,000 vertices, one `diffusion_operators` call each (every call meets a new size, so
its kernels compile: JAX compiles a program per array shape), against the reference on the same
meshes. Total seconds and the ratio.

**batch**: `ddgjax.batch.laplacian_apply` on a padded batch against a Python loop of single-mesh
calls (`throughput` below).

Run: `python benchmarks/learning.py` (about 15 minutes on 2 cores); `--k 32,128`, `--repeats 3`,
`--meshes disk.obj,beetle.off`; `--profile` splits ddgjax's time into its parts on each mesh
(intrinsic Delaunay `L` and `M`, eigensolve, gradient fit); `--sections batch --batch 16`.
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import robust_laplacian  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402
import trimesh  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, jit, run_sections, timed_interleaved  # noqa: E402

from ddgjax import Mesh, cpu_compiler_options  # noqa: E402
from ddgjax import batch as batched  # noqa: E402
from ddgjax.io import load_mesh  # noqa: E402
from ddgjax.laplacian import dirichlet_energy, laplacian_and_mass, laplacian_apply  # noqa: E402
from ddgjax.learn import diffusion_operators  # noqa: E402
from ddgjax.learn._gradient import gradient_frames_and_weights, neighbor_table  # noqa: E402
from ddgjax.mesh import grid, icosphere, torus  # noqa: E402
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


def precompute(args) -> None:
    meshes = [(name, load_mesh(SHARED / name)) for name in args.meshes if name]
    meshes.append(("icosphere(5)", icosphere(5)))
    print(
        "| mesh | nv | k | ddgjax first s | ddgjax min / median s | reference min / median s | ratio (medians) | ratio (min) | eig rel diff |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for k in map(int, args.k.split(",")):
        for name, mesh in meshes:
            run(name, mesh, k, args.repeats, args.profile)


def random_convex_mesh(n: int, rng: np.random.Generator) -> Mesh:
    """The convex hull of `n` random points on the unit sphere, consistently oriented (trimesh)."""
    points = rng.normal(size=(n, 3))
    hull = trimesh.convex.convex_hull(points / np.linalg.norm(points, axis=1, keepdims=True))
    return Mesh.from_arrays(np.asarray(hull.vertices), np.asarray(hull.faces))


def dataset(args) -> None:
    rng = np.random.default_rng(0)
    sizes = np.linspace(1000, 8000, args.dataset_meshes).astype(int)
    meshes = [random_convex_mesh(int(n), rng) for n in sizes]
    k = int(args.k.split(",")[0])
    ours(random_convex_mesh(500, rng), k)  # the process's first compilations (tracing machinery) out of the way
    seconds = {"ddgjax": 0.0, "reference": 0.0}
    for mesh in meshes:
        V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        seconds["ddgjax"] += timed(lambda mesh=mesh: ours(mesh, k))[0]
        seconds["reference"] += timed(lambda V=V, F=F: reference(V, F, k))[0]
    print(
        f"# dataset: {len(meshes)} meshes of distinct sizes {sizes[0]}..{sizes[-1]} vertices, k = {k}: "
        f"ddgjax {seconds['ddgjax']:.1f} s, reference {seconds['reference']:.1f} s, "
        f"ratio {seconds['ddgjax'] / seconds['reference']:.2f}x"
    )


def make_meshes(count: int, low: int, high: int, seed: int = 0) -> list:
    """`count` tori and grids with vertex counts spread over `[low, high]`, positions jittered."""
    rng = np.random.default_rng(seed)
    meshes = []
    for i, target in enumerate(np.linspace(low, high, count)):
        side = int(round(np.sqrt(target)))
        if i % 2 == 0:
            mesh = torus(n_major=max(3, int(round(target / max(3, side // 2)))), n_minor=max(3, side // 2))
        else:
            mesh = grid(side - 1, max(1, int(round(target / side)) - 1))
        edge = float(np.sqrt(np.sum(np.asarray(mesh.vertices[mesh.edges[0, 1]] - mesh.vertices[mesh.edges[0, 0]]) ** 2)))
        meshes.append(mesh.with_vertices(np.asarray(mesh.vertices) + 0.1 * edge * rng.uniform(-1, 1, (mesh.n_vertices, 3))))
    return meshes


def throughput(args) -> None:
    meshes = make_meshes(args.batch, args.min_vertices, args.max_vertices)
    rng = np.random.default_rng(1)
    shape = (lambda nv: (nv,)) if args.columns == 1 else (lambda nv: (nv, args.columns))
    values = [jnp.asarray(rng.standard_normal(shape(mesh.n_vertices))) for mesh in meshes]
    batch = batched.MeshBatch.from_meshes(meshes)
    u = batched.pad_vertex_values(values, n_vertices=batch.n_padded_vertices)
    total = sum(mesh.n_vertices for mesh in meshes)
    print(
        f"# {len(meshes)} meshes, {min(m.n_vertices for m in meshes)}..{max(m.n_vertices for m in meshes)} vertices "
        f"({total} in all), padded to B x nvp = {batch.batch_size} x {batch.n_padded_vertices}, "
        f"nfp = {batch.n_padded_faces}, overflow corner rows R = {batch.overflow_vertices.shape[1]}, "
        f"overflow edges K = {batch.overflow_edges.shape[1]}, columns = {args.columns}"
    )

    single_apply = jit(laplacian_apply)  # a user's jit keeps every size's program (the eager kernel keeps 8)

    def loop_apply(us):
        return [single_apply(mesh, x) for mesh, x in zip(meshes, us)]

    def loop_eager(us):
        return [laplacian_apply(mesh, x) for mesh, x in zip(meshes, us)]

    def loop_grad(us):
        return [energy_grad(mesh, x) for mesh, x in zip(meshes, us)]

    def energy_grad(mesh, x):
        return single_grad(mesh.vertices, mesh, x)

    single_grad = jax.jit(
        jax.grad(lambda V, mesh, x: dirichlet_energy(mesh.with_vertices(V), x)),
        compiler_options=cpu_compiler_options() or None,
    )
    batch_grad = jit(jax.grad(lambda V, b, x: jnp.sum(batched.dirichlet_energy(b.with_vertices(V), x))))
    user_jit = jit(batched.laplacian_apply)

    start = time.perf_counter()
    jax.block_until_ready(batched.laplacian_apply(batch, u))
    first = time.perf_counter() - start
    start = time.perf_counter()
    jax.block_until_ready(batched.laplacian_apply(batch, u))
    steady = time.perf_counter() - start
    start = time.perf_counter()
    jax.block_until_ready(loop_apply(values))
    loop_first = time.perf_counter() - start
    print(
        f"# compile: batched {1e3 * (first - steady):.0f} ms (one program); loop first calls {1e3 * loop_first:.0f} ms "
        f"({len({m.n_vertices for m in meshes})} programs)"
    )

    result = batched.unpad(batch, batched.laplacian_apply(batch, u))
    error = max(float(np.max(np.abs(r - np.asarray(s)))) for r, s in zip(result, loop_apply(values)))
    print(f"# max |batched - loop| = {error:.1e}")

    calls = {
        "batched laplacian_apply (eager call)": (batched.laplacian_apply, (batch, u)),
        "batched laplacian_apply in user jit": (user_jit, (batch, u)),
        "loop of jitted laplacian_apply (16 calls)": (loop_apply, (values,)),
        "loop of eager laplacian_apply (16 calls)": (loop_eager, (values,)),
        "batched grad_V sum Dirichlet energies": (batch_grad, (batch.vertices, batch, u)),
        "loop of grad_V Dirichlet energy": (loop_grad, (values,)),
    }
    calls = {name.replace("16", str(len(meshes))): call for name, call in calls.items()}
    for fn, call_args in calls.values():
        jax.block_until_ready(fn(*call_args))
    times, _ = timed_interleaved(calls, 5 * args.repeats, budget_s=args.budget)
    width = max(map(len, times))
    print(f"{'':{width}}  {'min / median ms':>18}  {'Mvertices/s (min)':>17}")
    for name, t in times.items():
        print(f"{name:{width}}  {fmt(t, 5 * args.repeats):>18}  {total / t[0] / 1e3:17.1f}")
    names = list(times)
    print(
        f"# ratio loop / batched (min): apply {times[names[2]][0] / times[names[0]][0]:.2f}x "
        f"(in user jit {times[names[2]][0] / times[names[1]][0]:.2f}x; eager loop {times[names[3]][0] / times[names[0]][0]:.2f}x), "
        f"gradient {times[names[5]][0] / times[names[4]][0]:.2f}x"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default="precompute,dataset,batch")
    parser.add_argument("--k", default="32,128", help="numbers of eigenpairs, comma separated (dataset: the first)")
    parser.add_argument("--repeats", type=int, default=3, help="rounds per mesh (precompute) or call (batch: 5 times as many)")
    parser.add_argument("--meshes", default=",".join(MESHES), help="shared meshes, comma separated (icosphere always)")
    parser.add_argument("--profile", action="store_true", help="split ddgjax's time into its parts")
    parser.add_argument("--dataset-meshes", type=int, default=12)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--min-vertices", type=int, default=2000)
    parser.add_argument("--max-vertices", type=int, default=20000)
    parser.add_argument("--columns", type=int, default=1)
    parser.add_argument("--budget", type=float, default=20.0, help="seconds of timed runs per batched call at most")
    run_sections({"precompute": precompute, "dataset": dataset, "batch": throughput}, parser.parse_args())


if __name__ == "__main__":
    main()
