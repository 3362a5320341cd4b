"""Scaling of ddgjax.sharding on 1, 2, 4 and 8 host CPU devices: a sharded batch and one partitioned mesh.

Each device count runs in its own subprocess (JAX fixes the device count when its backend starts:
`XLA_FLAGS=--xla_force_host_platform_device_count=N`), which prints its times as JSON; this script
prints the table. Workloads:

- **batch gradient**: `jax.jit(jax.vmap(jax.grad(E)))` of the Dirichlet energy `E(V)` of a fixed
  function over a batch of icosphere(4) shapes (2,562 vertices each), the batch sharded
  `P("batch")` (`shard_batch`). Strong scaling: 32 shapes whatever the device count; weak scaling:
  4 shapes per device.
- **batch flow**: `jax.jit(jax.vmap(...))` of 5 steps of `mean_curvature_flow(..., solver="cg")` on
  16 icosphere(3) shapes (strong scaling).
- **partitioned CG**: `sharded_cg` on `(L + M) x = b`, 200 CG iterations (`max_steps=200`,
  `throw=False`, so every device count does the same work). Strong scaling: icosphere(7) (163,842
  vertices); weak scaling: a torus with 20,000 vertices per device. Also one `sharded_laplacian_apply`
  on icosphere(7), and for reference `laplacian_apply` on one device.

Times are min / median over repeats of a compiled call (compilation reported apart), in ms;
speedup = time on 1 device / time on N (for weak scaling, the ideal is 1.0). On a machine with
fewer cores than devices the "devices" share the cores, so no speedup beyond the core count is
possible there: on the 2-core machine of benchmarks/README.md expect at most ~2x, and overhead
(halo exchange through memory, one thread per device) beyond it.

Run: `python benchmarks/sharding.py [--devices 1,2,4,8] [--repeats 5]`.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

RESULT = "RESULT "


def measure(function, repeats: int) -> dict:
    """`{"compile": s, "min": ms, "median": ms}` of a function of no arguments that returns a JAX pytree."""
    import jax
    import numpy as np

    start = time.perf_counter()
    jax.block_until_ready(function())
    first = time.perf_counter() - start
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function())
        samples.append(1e3 * (time.perf_counter() - start))
    return {"compile": first, "min": float(np.min(samples)), "median": float(np.median(samples))}


def child(repeats: int) -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    import ddgjax
    from ddgjax.laplacian import dirichlet_energy, laplacian_apply
    from ddgjax.mesh import icosphere, torus
    from ddgjax.pde import mean_curvature_flow
    from ddgjax.sharding import batch_sharding, partition_vertices, shard_batch, sharded_cg, sharded_laplacian_apply

    n = jax.device_count()
    rng = np.random.default_rng(0)
    options = ddgjax.cpu_compiler_options() or None
    results = {}

    def batch(mesh, size):
        noise = 0.01 * rng.standard_normal((size, mesh.n_vertices, 3))
        return shard_batch(np.asarray(mesh.vertices)[None] + noise, batch_sharding())

    sphere4 = icosphere(4)
    u = jnp.sin(3.0 * sphere4.vertices[:, 0])
    gradient = jax.jit(jax.vmap(jax.grad(lambda V: dirichlet_energy(sphere4.with_vertices(V), u))), compiler_options=options)
    for name, size in (("batch gradient, strong (32 x 2,562 v)", 32), ("batch gradient, weak (4 x 2,562 v per device)", 4 * n)):
        V = batch(sphere4, size)
        results[name] = measure(lambda V=V: gradient(V), repeats)

    sphere3 = icosphere(3)
    flow = jax.jit(
        jax.vmap(lambda V: mean_curvature_flow(sphere3.with_vertices(V), tau=1e-3, steps=5, solver="cg").value),
        compiler_options=options,
    )
    V = batch(sphere3, 16)
    results["batch flow, strong (16 x 642 v, 5 steps)"] = measure(lambda: flow(V), repeats)

    big = icosphere(7)
    partition = partition_vertices(big)
    b = partition.shard(rng.standard_normal(big.n_vertices))
    results["partitioned apply, strong (163,842 v)"] = measure(lambda: sharded_laplacian_apply(partition, b), repeats)
    results["partitioned CG, strong (163,842 v, 200 it.)"] = measure(
        lambda: sharded_cg(partition, b, shift=1.0, max_steps=200, rtol=1e-30, throw=False).value, repeats
    )
    ring = torus(n_major=200 * n, n_minor=100)
    partition = partition_vertices(ring)
    b = partition.shard(rng.standard_normal(ring.n_vertices))
    results["partitioned CG, weak (20,000 v per device, 200 it.)"] = measure(
        lambda: sharded_cg(partition, b, shift=1.0, max_steps=200, rtol=1e-30, throw=False).value, repeats
    )
    if n == 1:
        x = jnp.asarray(rng.standard_normal(big.n_vertices))
        results["laplacian_apply, one device (163,842 v)"] = measure(lambda: laplacian_apply(big, x), repeats)
    print(RESULT + json.dumps({"devices": n, "results": results}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", default="1,2,4,8")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.repeats)
        return
    runs = {}
    for n in map(int, args.devices.split(",")):
        env = dict(os.environ)
        env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={n}").strip()
        output = subprocess.run(
            [sys.executable, __file__, "--child", "--repeats", str(args.repeats)], env=env, capture_output=True, text=True
        )
        if output.returncode:
            sys.exit(f"{n} devices failed:\n{output.stderr[-3000:]}")
        line = next(line for line in output.stdout.splitlines() if line.startswith(RESULT))
        runs[n] = json.loads(line[len(RESULT) :])["results"]
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, float64; ms min / median (compile s)")
    counts = list(runs)
    header = ["workload"] + [f"{n} dev" for n in counts] + [f"speedup {n}" for n in counts[1:]]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for name in runs[counts[0]]:
        cells = [name]
        for n in counts:
            entry = runs[n].get(name)
            cells.append("" if entry is None else f"{entry['min']:.1f} / {entry['median']:.1f} ({entry['compile']:.1f})")
        base = runs[counts[0]][name]["min"]
        cells += [f"{base / runs[n][name]['min']:.2f}" if name in runs[n] else "" for n in counts[1:]]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
