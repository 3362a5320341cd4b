"""Shape optimisation: the PyTorch3D-style mesh-fitting loop under `minimize_shape`, and the Large Steps solves.

Sections (`--sections`, comma-separated; all by default):

- **fit**: per-iteration time of the mesh-fitting loop of PyTorch3D's tutorial (an icosphere fitted to
  points sampled from an ellipsoid: Chamfer distance of `n` fresh surface samples against `n` target
  points, plus edge-length, normal-consistency and uniform Laplacian-smoothing regularisers), one
  jitted step (`value_and_grad`, uniform Adam, the Large Steps solve) in `lax.scan` chunks, on
  `icosphere(4)` (2,562 vertices, `n = 5,000`) and `icosphere(6)` (40,962 vertices, `n = 10,000`);
  compile time apart. The same loop in torch (PyTorch3D's ops) when `torch` imports; otherwise a
  line says it is absent.
- **large_steps**: `from_parameters` (one solve with the kept factor, `(nv, 3)` right-hand side) and
  its reverse-mode derivative, jitted, per second, on the same meshes.

Times: min / median ms over interleaved repeats (`benchmarks/solve.py`'s `timed_interleaved`).
Run: `python benchmarks/optim.py [--sections fit,large_steps] [--steps 20] [--repeats 5]`.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, jit, optional, run_sections, timed_interleaved, warmed  # noqa: E402

from ddgjax.mesh import icosphere  # noqa: E402
from ddgjax.optim import (  # noqa: E402
    adam_uniform,
    chamfer_distance,
    edge_length_loss,
    laplacian_smoothing_loss,
    large_steps,
    minimize_shape,
    normal_consistency_loss,
    sample_points,
)

SIZES = ((4, 5_000), (6, 10_000))  # (icosphere subdivisions, samples per Chamfer term)


def _fit_loss(target, n):
    def loss(mesh, key):
        points = sample_points(mesh, n, key)
        return (
            chamfer_distance(points, target)
            + 1.0 * edge_length_loss(mesh)
            + 0.01 * normal_consistency_loss(mesh)
            + 0.1 * laplacian_smoothing_loss(mesh)
        )

    return loss


def fit(args):
    print("\n## fit: mesh-fitting loop (Chamfer + edge + normal + Laplacian; Large Steps + uniform Adam), per iteration")
    print(f"{'mesh':>16} {'vertices':>9} {'samples':>8} {'compile s':>10} {'ms / iteration':>15} {'iterations / s':>15}")
    for subdivisions, n in SIZES:
        source = icosphere(subdivisions)
        target_mesh = icosphere(5).with_vertices(icosphere(5).vertices * jnp.array([1.3, 1.0, 0.7]))
        target = sample_points(target_mesh, n, jax.random.key(1))
        result = minimize_shape(
            _fit_loss(target, n),
            source,
            steps=args.steps,
            chunk_size=args.steps,
            optimizer=adam_uniform(1e-2),
            key=jax.random.key(0),
            progress=False,
        )
        per_step = 1e3 * result.run_time / args.steps
        print(
            f"{'icosphere(' + str(subdivisions) + ')':>16} {source.n_vertices:>9} {n:>8} {result.compile_time:>10.2f} "
            f"{per_step:>15.1f} {1e3 / per_step:>15.1f}"
        )
    torch = optional("torch")
    if torch is None:
        print("torch is not installed: no torch / PyTorch3D comparison (the loop above is what it would be compared with)")
    else:
        print(f"torch {torch.__version__} imports, but the torch loop is not written yet (PyTorch3D would be needed too)")


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


SECTIONS = {"fit": fit, "large_steps": large_steps_section}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default=",".join(SECTIONS), help=f"comma-separated, of: {', '.join(SECTIONS)}")
    parser.add_argument("--steps", type=int, default=20, help="iterations timed per mesh (after compilation)")
    parser.add_argument("--repeats", type=int, default=5)
    run_sections(SECTIONS, parser.parse_args())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
