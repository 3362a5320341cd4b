"""Deformation from handles: ddgjax `biharmonic_deformation` and `arap` against libigl, one process.

On icospheres and open cylinders of ~10k and ~40k vertices, two handle regions (the caps: the
bottom held, the top translated and rotated), ddgjax jitted on the rest positions and the handles'
positions (nothing folded at compile time):

- **biharmonic**: `biharmonic_deformation(mesh, order=2)` against `V + igl.harmonic(V, F, b, bc - V[b], 2)`,
  one solve each (factorisation included), warm.
- **arap**: the spokes energy, from the same start (`U = V; U[b] = bc`). Per local-global step:
  ddgjax's time for `N + 1` steps minus one step, over `N` (its factorisation is inside the call;
  its setup shows in the one-step time); libigl's `arap_solve` with `max_iter = N`, its
  `arap_precomputation` timed apart. To convergence:
  ddgjax with `rtol` (largest move of a step over the bounding-box diagonal) against libigl's
  `arap_solve` with `max_iter` the number of steps its own iteration needs to meet the same test
  (counted beforehand one step at a time), plus its precomputation. The answers are compared.
- **gradient** (in the arap table): `jax.value_and_grad` of `sum(w * arap(...))` in `fixed_values`
  (implicit: one CG solve preconditioned by the kept factor) against the jitted forward call; up to
  `--gradient-max-vertices` (20,000 by default: at 41k one gradient takes minutes).

Times: min / median ms over interleaved repeats (`benchmarks/solve.py`'s `timed_interleaved`);
compile time apart. Run: `python benchmarks/deform.py [--meshes NAMES] [--rtol 1e-3] [--steps 10]
[--gradient-max-vertices 20000]` (~5 min on 2 cores; ~13 min with `--gradient-max-vertices 50000`).
"""

from __future__ import annotations

import pathlib
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, jit, mesh_sections_parser, optional, run_sections, timed_interleaved, warmed  # noqa: E402

from ddgjax.deform import arap, biharmonic_deformation  # noqa: E402
from ddgjax.mesh import cylinder, icosphere  # noqa: E402

igl = optional("igl")
DEFAULT_MESHES = "icosphere(5),cylinder(100),icosphere(6),cylinder(200)"


def problem(name):
    """`(mesh, handles b, their new positions bc)`: `icosphere(s)` with its caps `|z| > 0.8`, or
    `cylinder(n)` (n x n rings, radius 1, height 4) with its 4 end rings each side; the bottom held,
    the top turned 45 degrees about z, tilted 20 degrees about x and moved by (0.3, 0, 0.2)."""
    size = int(name[name.index("(") + 1 : -1])
    mesh = icosphere(size) if name.startswith("icosphere(") else cylinder(size, size - 1, radius=1.0, height=4.0)
    V = np.asarray(mesh.vertices)
    z = V[:, 2]
    span = z.max() - z.min()
    bottom = np.flatnonzero(z < z.min() + 0.1 * span)
    top = np.flatnonzero(z > z.max() - 0.1 * span)
    twist, tilt = np.radians(45.0), np.radians(20.0)
    Rz = np.array([[np.cos(twist), -np.sin(twist), 0], [np.sin(twist), np.cos(twist), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    centre = V[top].mean(axis=0)
    moved = (V[top] - centre) @ (Rx @ Rz).T + centre + np.array([0.3, 0.0, 0.2])
    b = np.concatenate([bottom, top])
    bc = np.concatenate([V[bottom], moved])
    return mesh, b, bc


def compiled(fn, *args):
    """`(fn, compile ms)`: `fn` jitted and compiled ahead of time for `args`."""
    start = time.perf_counter()
    fn.lower(*args).compile()
    return fn, 1e3 * (time.perf_counter() - start)


def ratio(a, b):
    return f"{a[0] / b[0]:.2f}x"


def section_biharmonic(args):
    print("\n# biharmonic deformation (k = 2): ddgjax jitted in (V, fixed_values), libigl harmonic(k = 2) + V; one solve each")
    print("| mesh | nv | handles | ddgjax | libigl | ratio | compile | max abs diff |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.meshes:
        _biharmonic_row(name, args)


def _biharmonic_row(name, args):
    mesh, b, bc = problem(name)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
    inputs = (mesh.vertices, jnp.asarray(bc))
    ours, compile_ms = compiled(
        jit(lambda v, bc: biharmonic_deformation(mesh.with_vertices(v), fixed_vertices=b, fixed_values=bc, order=2)),
        *inputs,
    )
    calls = {"ddgjax": (ours, inputs)}
    if igl is not None:
        b32 = b.astype(np.int32)
        calls["libigl"] = (lambda: V + igl.harmonic(V, F, b32, bc - V[b32], 2), ())
    times, results = timed_interleaved(warmed(calls), args.repeats, args.budget)
    peer = times.get("libigl")
    diff = np.abs(np.asarray(results["ddgjax"]) - results["libigl"]).max() if peer else float("nan")
    print(
        f"| {name} | {mesh.n_vertices:,} | {b.size} | {fmt(times['ddgjax'], args.repeats)} | "
        f"{fmt(peer, args.repeats)} | {ratio(times['ddgjax'], peer) if peer else '-'} | {compile_ms:.0f} | {diff:.1e} |"
    )


def igl_steps_to(V, F, b, bc, U0, rtol, max_steps):
    """libigl's ARAP steps until a step moves no vertex by more than `rtol` times the bounding-box diagonal."""
    data = _igl_arap(V, F, b, 1)
    scale = np.linalg.norm(V.max(axis=0) - V.min(axis=0))
    U = U0
    for step in range(1, max_steps + 1):
        new = igl.arap_solve(bc, data, U)
        change = np.abs(new - U).max() / scale
        U = new
        if change <= rtol:
            return step, U
    return max_steps, U


def _igl_arap(V, F, b, max_iter):
    data = igl.ARAPData()
    data.energy = igl.ARAP_ENERGY_TYPE_SPOKES
    data.max_iter = max_iter
    igl.arap_precomputation(V, F, 3, b, data)
    return data


def section_arap(args):
    steps = args.steps
    print(
        f"\n# ARAP (spokes): per local-global step (from {steps} steps), precomputation, and to convergence at "
        f"rtol = {args.rtol:g}; gradient of sum(w * V') in fixed_values against the forward call"
    )
    print(
        "| mesh | nv | ddgjax per step | libigl per step | ratio | ddgjax 1 step (setup + step) | libigl precomputation | steps ddgjax / libigl "
        "| ddgjax to rtol | libigl precomputation + solve to rtol | ratio | max abs diff | ddgjax value + gradient | "
        "gradient / forward | compile forward / gradient |"
    )
    print("|" + "---|" * 15)
    for name in args.meshes:
        _arap_row(name, args)


def _arap_row(name, args):
    steps = args.steps
    mesh, b, bc = problem(name)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
    b32 = b.astype(np.int32)
    U0 = V.copy()
    U0[b] = bc
    Vj, bcj, U0j = mesh.vertices, jnp.asarray(bc), jnp.asarray(U0)
    w = jnp.asarray(np.random.default_rng(0).standard_normal(V.shape))

    def fixed_steps(n):
        # rtol far below round-off: exactly `n` steps (outcome max_steps_reached, not raised)
        return jit(
            lambda v, bc, U: (
                arap(
                    mesh.with_vertices(v), fixed_vertices=b, fixed_values=bc, initial=U, max_steps=n, rtol=1e-300, throw=False
                ).value
            )
        )

    def converged(v, bc, U):
        solution = arap(
            mesh.with_vertices(v),
            fixed_vertices=b,
            fixed_values=bc,
            initial=U,
            rtol=args.rtol,
            max_steps=args.max_steps,
            throw=False,
        )
        return solution.value, solution.stats["num_steps"]

    def loss(v, bc, U):
        return jnp.vdot(w, converged(v, bc, U)[0])

    one, _ = compiled(fixed_steps(1), Vj, bcj, U0j)
    many, _ = compiled(fixed_steps(steps + 1), Vj, bcj, U0j)
    forward, compile_forward = compiled(jit(converged), Vj, bcj, U0j)
    with_gradient = mesh.n_vertices <= args.gradient_max_vertices
    if with_gradient:
        gradient, compile_gradient = compiled(jit(jax.value_and_grad(loss, argnums=1)), Vj, bcj, U0j)

    calls = {
        "ddgjax 1 step": (one, (Vj, bcj, U0j)),
        f"ddgjax {steps + 1} steps": (many, (Vj, bcj, U0j)),
        "ddgjax to rtol": (forward, (Vj, bcj, U0j)),
    }
    if with_gradient:
        calls["ddgjax value_and_grad"] = (gradient, (Vj, bcj, U0j))
    if igl is not None:
        their_steps, their_answer = igl_steps_to(V, F, b32, bc, U0, args.rtol, args.max_steps)
        data_steps = _igl_arap(V, F, b32, steps)
        data_converge = _igl_arap(V, F, b32, their_steps)
        calls["libigl precomputation"] = (lambda: _igl_arap(V, F, b32, 1) and None, ())
        calls[f"libigl {steps} steps"] = (lambda: igl.arap_solve(bc, data_steps, U0), ())
        calls["libigl solve to rtol"] = (lambda: igl.arap_solve(bc, data_converge, U0), ())
    # no separate warm-up: ddgjax's programs are compiled ahead; a call under a second warms up in round 0
    times, results = timed_interleaved(calls, args.repeats, args.budget)
    our_steps = int(results["ddgjax to rtol"][1])
    ours_per = (times[f"ddgjax {steps + 1} steps"][0] - times["ddgjax 1 step"][0]) / steps
    line = [name, f"{mesh.n_vertices:,}", f"{ours_per:.2f}"]
    if igl is not None:
        theirs_per = times[f"libigl {steps} steps"][0] / steps
        precompute = times["libigl precomputation"]
        theirs_total = precompute[0] + times["libigl solve to rtol"][0]
        diff = np.abs(np.asarray(results["ddgjax to rtol"][0]) - their_answer).max()
        line += [
            f"{theirs_per:.2f}",
            f"{ours_per / theirs_per:.2f}x",
            fmt(times["ddgjax 1 step"], args.repeats),
            fmt(precompute, args.repeats),
            f"{our_steps} / {their_steps}",
            fmt(times["ddgjax to rtol"], args.repeats),
            f"{theirs_total:.1f}",
            f"{times['ddgjax to rtol'][0] / theirs_total:.2f}x",
            f"{diff:.1e}",
        ]
    else:
        line += [
            "-",
            "-",
            fmt(times["ddgjax 1 step"], args.repeats),
            "-",
            f"{our_steps} / -",
            fmt(times["ddgjax to rtol"], args.repeats),
            "-",
            "-",
            "-",
        ]
    if with_gradient:
        line += [
            fmt(times["ddgjax value_and_grad"], args.repeats),
            ratio(times["ddgjax value_and_grad"], times["ddgjax to rtol"]),
            f"{compile_forward:.0f} / {compile_gradient:.0f}",
        ]
    else:
        line += ["-", "-", f"{compile_forward:.0f} / -"]
    print("| " + " | ".join(line) + " |")


SECTIONS = {"biharmonic": section_biharmonic, "arap": section_arap}


def main(argv=None) -> int:
    parser = mesh_sections_parser(__doc__.splitlines()[0], SECTIONS, DEFAULT_MESHES, budget=5.0)
    parser.add_argument("--rtol", type=float, default=1e-3, help="ARAP stopping test, as ddgjax's `rtol`")
    parser.add_argument("--steps", type=int, default=10, help="ARAP steps for the per-step time")
    parser.add_argument("--max-steps", type=int, default=1000, dest="max_steps")
    parser.add_argument(
        "--gradient-max-vertices",
        type=int,
        default=20_000,
        dest="gradient_max_vertices",
        help="time the ARAP gradient only up to this size (at 41k it takes ~2.5 min a call)",
    )
    run_sections(SECTIONS, parser.parse_args(argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
