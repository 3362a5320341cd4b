"""Shape optimisation: the PyTorch3D-style mesh-fitting loop under `minimize_shape`, and the Large Steps solves.

Sections (`--sections`, comma-separated; all by default):

- **fit**: per-iteration time of the mesh-fitting loop of PyTorch3D's tutorial (an icosphere fitted to
  points sampled from an ellipsoid: Chamfer distance of `n` fresh surface samples against `n` target
  points (its nearest-neighbour search: `method="auto"`, SciPy's k-d trees on a CPU), plus edge-length, normal-consistency and uniform Laplacian-smoothing regularisers), one
  jitted step (`value_and_grad`, uniform Adam, the Large Steps solve) in `lax.scan` chunks, on
  `icosphere(4)` (2,562 vertices, `n = 5,000`) and `icosphere(6)` (40,962 vertices, `n = 10,000`);
  compile time (first call less second) apart, and per iteration the difference of runs of `--steps`
  and twice as many (so the host setup, the Large Steps factorisation, is left out). The same loop in torch with the Large Steps authors' `largesteps` package
  (`compute_matrix`, `from_differential` with cholespy, `AdamUniform`) and the same losses in torch
  ops, when both import (`pip install torch largesteps`); otherwise a line says they are absent.
- **quality**: the final Chamfer distance of both loops after `--quality-steps` iterations
  (icosphere(4), 5,000 samples, 20,000-sample estimate; the target against itself is the floor).
- **large_steps**: `from_parameters` (one solve with the kept factor, `(nv, 3)` right-hand side) and
  its reverse-mode derivative, jitted, per second, on the same meshes.

Times: min / median ms over interleaved repeats (`benchmarks/solve.py`'s `timed_interleaved`).
Run: `python benchmarks/optim.py [--sections fit,quality,large_steps] [--steps 20] [--quality-steps 200] [--repeats 5]`.
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
from solve import fmt, jit, optional, run_sections, timed_interleaved, warmed  # noqa: E402

from ddgjax.mesh import icosphere  # noqa: E402
from ddgjax.optim import (  # noqa: E402
    adam_uniform,
    chamfer_distance,
    large_steps,
    mesh_fitting_loss,
    minimize_shape,
    sample_points,
)

SIZES = ((4, 5_000), (6, 10_000))  # (icosphere subdivisions, samples per Chamfer term)


def _fit_loss(target, n):
    return mesh_fitting_loss(target, n_samples=n)  # PyTorch3D's weights: edge 1, normal 0.01, Laplacian 0.1


def fit(args):
    print("\n## fit: mesh-fitting loop (Chamfer + edge + normal + Laplacian; Large Steps + uniform Adam), per iteration")
    print(f"{'mesh':>16} {'vertices':>9} {'samples':>8} {'compile s':>10} {'ms / iteration':>15} {'iterations / s':>15}")
    per_steps = []
    for subdivisions, n in SIZES:
        source = icosphere(subdivisions)
        target_mesh = icosphere(5).with_vertices(icosphere(5).vertices * jnp.array([1.3, 1.0, 0.7]))
        target = sample_points(target_mesh, n, key=jax.random.key(1))
        loss, optimizer = _fit_loss(target, n), adam_uniform(1e-2)  # the same objects: one compiled chunk

        def seconds(steps, loss=loss, optimizer=optimizer, source=source):
            # progress=True runs one compiled chunk of `args.steps` per call, whatever `steps` is
            start = time.perf_counter()
            settings = {"chunk_size": args.steps, "optimizer": optimizer, "key": jax.random.key(0), "progress": True}
            jax.block_until_ready(minimize_shape(loss, source, steps=steps, **settings).value)
            return time.perf_counter() - start

        first, once, twice = seconds(args.steps), seconds(args.steps), seconds(2 * args.steps)
        # The difference of the runs of `steps` and `2 steps` leaves out the setup (the Large Steps factorisation).
        per_step = 1e3 * (twice - once) / args.steps
        per_steps.append(per_step)
        print(
            f"{'icosphere(' + str(subdivisions) + ')':>16} {source.n_vertices:>9} {n:>8} {first - once:>10.2f} "
            f"{per_step:>15.1f} {1e3 / per_step:>15.1f}"
        )
    torch = optional("torch")
    largesteps = optional("largesteps")
    if torch is None or largesteps is None:
        print("torch or largesteps is not installed (pip install torch largesteps): no torch comparison")
        return
    print(
        f"\n## the same loop in torch {torch.__version__} + largesteps (the paper's code: cholespy solve, AdamUniform), float32; ddgjax float64"
    )
    print(f"{'mesh':>16} {'vertices':>9} {'samples':>8} {'ms / iteration':>15} {'iterations / s':>15} {'ddgjax / torch':>15}")
    for (subdivisions, n), ours in zip(SIZES, per_steps):
        source = icosphere(subdivisions)
        target_mesh = icosphere(5).with_vertices(icosphere(5).vertices * jnp.array([1.3, 1.0, 0.7]))
        target = np.asarray(sample_points(target_mesh, n, key=jax.random.key(1)))
        per_step = 1e3 * _torch_fit(torch, source, target, n, args.steps)[0]
        print(
            f"{'icosphere(' + str(subdivisions) + ')':>16} {source.n_vertices:>9} {n:>8} {per_step:>15.1f} "
            f"{1e3 / per_step:>15.1f} {ours / per_step:>15.2f}"
        )


def _torch_fit(torch, source, target, n, steps) -> tuple[float, np.ndarray]:
    """Seconds per iteration of the same loop in torch: the same losses written with torch ops (PyTorch3D's
    definitions, which need no PyTorch3D), largesteps' `compute_matrix` / `from_differential` and
    `AdamUniform`; one warm-up iteration, then `steps` timed ones. Returns (seconds per iteration,
    the final vertices)."""
    from largesteps.optimize import AdamUniform
    from largesteps.parameterize import from_differential, to_differential

    torch.manual_seed(0)
    dtype = torch.float32  # largesteps' CholeskySolver is cholespy's float32 solver
    V0 = torch.tensor(np.asarray(source.vertices), dtype=dtype)
    F = torch.tensor(np.asarray(source.faces), dtype=torch.int64)
    edges = torch.tensor(np.asarray(source.edges), dtype=torch.int64)
    edge_faces = torch.tensor(np.asarray(source.edge_faces)[:, :2], dtype=torch.int64)
    target = torch.tensor(target, dtype=dtype)
    degree = torch.bincount(edges.reshape(-1), minlength=V0.shape[0]).to(dtype)
    # largesteps' compute_matrix puts its matrix on CUDA unconditionally: the same I + lambda L (uniform
    # graph Laplacian, lambda = 10) built here on the CPU.
    nv = V0.shape[0]
    rows = torch.cat([torch.arange(nv), edges[:, 0], edges[:, 1]])
    cols = torch.cat([torch.arange(nv), edges[:, 1], edges[:, 0]])
    values = torch.cat([1 + 10.0 * degree, -10.0 * torch.ones(2 * edges.shape[0], dtype=dtype)])
    M = torch.sparse_coo_tensor(torch.stack([rows, cols]), values, (nv, nv), check_invariants=True).coalesce()
    u = to_differential(M, V0).clone().requires_grad_(True)
    optimizer = AdamUniform([u], lr=1e-2)

    def loss_of(V):
        corners = V[F]
        cross = torch.linalg.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        areas = 0.5 * torch.linalg.norm(cross, dim=1)
        faces = torch.multinomial(areas.detach(), n, replacement=True)
        r1, r2 = torch.rand(n, 1, dtype=V.dtype).sqrt(), torch.rand(n, 1, dtype=V.dtype)
        c = corners[faces]
        points = (1 - r1) * c[:, 0] + r1 * (1 - r2) * c[:, 1] + r1 * r2 * c[:, 2]
        distances = torch.cdist(points, target) ** 2
        chamfer = distances.min(dim=1).values.mean() + distances.min(dim=0).values.mean()
        edge = ((V[edges[:, 1]] - V[edges[:, 0]]) ** 2).sum(dim=1).mean()
        normals = cross / torch.linalg.norm(cross, dim=1, keepdim=True)
        normal = (1 - (normals[edge_faces[:, 0]] * normals[edge_faces[:, 1]]).sum(dim=1)).mean()
        pull = torch.zeros_like(V).index_add_(0, edges[:, 0], V[edges[:, 1]]).index_add_(0, edges[:, 1], V[edges[:, 0]])
        laplacian = torch.linalg.norm(pull / degree[:, None] - V, dim=1).mean()
        return chamfer + 1.0 * edge + 0.01 * normal + 0.1 * laplacian

    def step():
        optimizer.zero_grad()
        loss_of(from_differential(M, u, "Cholesky")).backward()
        optimizer.step()

    step()
    start = time.perf_counter()
    for _ in range(steps):
        step()
    seconds = (time.perf_counter() - start) / steps
    with torch.no_grad():
        return seconds, from_differential(M, u, "Cholesky").numpy().astype(np.float64)


def quality(args):
    """The final Chamfer distance of both loops after the same iterations (icosphere(4), 5,000 samples)."""
    torch, largesteps = optional("torch"), optional("largesteps")
    if torch is None or largesteps is None:
        print("torch or largesteps is not installed: no quality comparison")
        return
    steps, n = args.quality_steps, 5_000
    source = icosphere(4)
    target_mesh = icosphere(5).with_vertices(icosphere(5).vertices * jnp.array([1.3, 1.0, 0.7]))
    target = sample_points(target_mesh, n, key=jax.random.key(1))
    ours = minimize_shape(
        _fit_loss(target, n), source, steps=steps, optimizer=adam_uniform(1e-2), key=jax.random.key(0), progress=False
    )
    theirs = source.with_vertices(jnp.asarray(_torch_fit(torch, source, np.asarray(target), n, steps)[1]))
    reference = sample_points(target_mesh, 20_000, key=jax.random.key(8))
    measure = lambda mesh: float(chamfer_distance(sample_points(mesh, 20_000, key=jax.random.key(7)), reference))
    print(f"\n## quality: Chamfer distance to the target after {steps} iterations (20,000 samples each side)")
    print(
        f"  start {measure(source):.3e}   ddgjax {measure(ours.mesh()):.3e}   torch + largesteps {measure(theirs):.3e}   "
        f"sampling floor (target vs itself) {measure(target_mesh):.3e}"
    )


def large_steps_section(args):
    print("\n## large_steps: from_parameters (one solve, kept factor) and its VJP, ms (min / median)")
    print(f"{'mesh':>16} {'vertices':>9} {'solve':>16} {'solve VJP':>16} {'solves / s':>12}")
    for subdivisions, _ in SIZES:
        mesh = icosphere(subdivisions)
        reparam = large_steps(mesh, lambda_=10.0)
        U = reparam.to_parameters(mesh.vertices)
        solve = jit(lambda U, r=reparam: r.from_parameters(U))
        vjp = jit(lambda U, g, r=reparam: jax.vjp(r.from_parameters, U)[1](g)[0])
        calls = warmed({"solve": (solve, (U,)), "vjp": (vjp, (U, U))})
        times, _ = timed_interleaved(calls, args.repeats, budget_s=5.0)
        print(
            f"{'icosphere(' + str(subdivisions) + ')':>16} {mesh.n_vertices:>9} {fmt(times['solve'], args.repeats):>16} "
            f"{fmt(times['vjp'], args.repeats):>16} {1e3 / times['solve'][1]:>12.0f}"
        )


SECTIONS = {"fit": fit, "quality": quality, "large_steps": large_steps_section}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default=",".join(SECTIONS), help=f"comma-separated, of: {', '.join(SECTIONS)}")
    parser.add_argument("--steps", type=int, default=20, help="iterations timed per mesh (after compilation)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--quality-steps", type=int, default=200, help="iterations of both loops before comparing the fit")
    run_sections(SECTIONS, parser.parse_args())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
