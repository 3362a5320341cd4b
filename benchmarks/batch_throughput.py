"""Batched Laplacian throughput: `ddgjax.batch.laplacian_apply` on a padded batch against a loop of single-mesh calls.

A learning pipeline applies the cotan Laplacian to a batch of meshes of different sizes at every
step. Two ways with ddgjax: one call of `ddgjax.batch.laplacian_apply` on a `MeshBatch` (padded to
bucketed sizes, one compiled program per bucket), or a Python loop of
`ddgjax.laplacian.laplacian_apply(mesh, u)` over the meshes (one compiled program per mesh size,
each compiled before timing: jitted by the caller, since the eager kernel keeps the programs of
its 8 most recent sizes and a loop over more sizes recompiles on every call, also timed). Both compute the same `L u` per mesh (checked).

Meshes (`--batch`, default 16): tori and grids whose vertex counts are spread evenly over
`--min-vertices` .. `--max-vertices` (default 2,000 .. 20,000), positions jittered by 10 % of an edge
so no two meshes share geometry; `--columns k` applies to `(nv, k)` values (default 1: `(nv,)`).
Printed: the padded sizes, compile time of the batched program (first call minus a steady call),
min / median ms over `--repeats` interleaved rounds (`benchmarks/solve.py`'s `timed_interleaved`),
throughput in real (unpadded) vertices per second, and the ratio loop / batched.
Also timed: the batched call inside a user's `jax.jit` (compiled with `ddgjax.cpu_compiler_options()`),
and the reverse pass of the summed Dirichlet energy in the positions, batched and looped.

Run: `python benchmarks/batch_throughput.py [--batch 16] [--min-vertices 2000] [--max-vertices 20000] [--repeats 15]`.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, jit, run_sections, timed_interleaved  # noqa: E402

from ddgjax import batch as batched  # noqa: E402
from ddgjax.laplacian import dirichlet_energy, laplacian_apply  # noqa: E402
from ddgjax.mesh import grid, torus  # noqa: E402


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
        f"nfp = {batch.n_padded_faces}, corners per vertex w = {batch.vertex_corners.shape[2]}, columns = {args.columns}"
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
        compiler_options=__import__("ddgjax").cpu_compiler_options() or None,
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
    times, _ = timed_interleaved(calls, args.repeats, budget_s=args.budget)
    width = max(map(len, times))
    print(f"{'':{width}}  {'min / median ms':>18}  {'Mvertices/s (min)':>17}")
    for name, t in times.items():
        print(f"{name:{width}}  {fmt(t, args.repeats):>18}  {total / t[0] / 1e3:17.1f}")
    names = list(times)
    print(
        f"# ratio loop / batched (min): apply {times[names[2]][0] / times[names[0]][0]:.2f}x "
        f"(in user jit {times[names[2]][0] / times[names[1]][0]:.2f}x; eager loop {times[names[3]][0] / times[names[0]][0]:.2f}x), "
        f"gradient {times[names[5]][0] / times[names[4]][0]:.2f}x"
    )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--min-vertices", type=int, default=2000)
    parser.add_argument("--max-vertices", type=int, default=20000)
    parser.add_argument("--columns", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--budget", type=float, default=20.0, help="seconds of timed runs per call at most")
    parser.add_argument("--sections", default="throughput")
    run_sections({"throughput": throughput}, parser.parse_args())
