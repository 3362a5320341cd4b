"""Euler flow on surfaces: ddgjax `euler_flow` (spectral) against a NumPy + SciPy implementation of the same method.

The method (Azencot, Weissmann, Ovsjanikov, Wardetzky & Ben-Chen, "Functional Fluids on Surfaces",
SGP 2014): vorticity `w = Phi a` in the first `k` eigenfunctions of `L phi = lambda M phi` (cotan
Laplacian, lumped Voronoi mass, M-orthonormal), stream function `psi = Phi b`, `b_i = -a_i / lambda_i`,
and `da_k/dt = -sum_ij W_kij b_i (a_j + f_j) - nu lambda_k a_k` with the advection tensor
`W_kij = integral phi_k J(phi_i, phi_j)`, `J(p, q) = n . (grad p x grad q)`, `f = 2 Omega z`;
one implicit-midpoint step per `tau`. ddgjax solves the step's equation by three Newton steps, the
NumPy peer by fixed-point iteration to round-off (5 iterations a step at `tau = 0.01`: fewer
flops than Newton's Jacobian and solve); both reach the same midpoint. The NumPy peer
(`numpy_basis`, `numpy_flow`) is what a user would write: libigl's `cotmatrix` / `massmatrix` /
`grad`, SciPy's `eigsh` shift-invert, W by blocked matmuls over faces, one `(k, k^2)` contraction
per fixed-point iteration, vertex values reconstructed only at saved states.

On `icosphere(5)` (10,242 vertices; ~4 min with 3 repeats on 2 cores) and, with `--levels 5,7`,
`icosphere(7)` (163,842 vertices: each basis build takes minutes, run it with `--repeats 1`), the
same arrays for both:

- **basis**: eigenpairs + advection tensor, `fluid_basis` (jitted in the vertex positions) against
  `numpy_basis`;
- **steps**: `--steps` implicit-midpoint steps saving every `--save-every` (k = `--k`), a kept
  basis: steps per second of each, and with only the final state saved ("steps only");
- **gradient**: `jax.value_and_grad` of `sum(c * final vorticity)` in the initial vorticity against
  the same loss's forward run (both jitted with `ddgjax.cpu_compiler_options()`).

Times: min / median ms over interleaved repeats (`benchmarks/solve.py`'s `timed_interleaved`);
compile time apart. Run: `python benchmarks/fluids.py [--levels 5,7] [--k 64] [--steps 1000]
[--save-every 100] [--repeats 5]`; `python benchmarks/fluids.py --check` verifies the NumPy peer
(icosphere(3): invariants, a steady spherical harmonic, the Rossby-Haurwitz rate) and, when
`ddgjax.fluids` imports, compares the two implementations' vorticity at vertices after 100 steps.
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
import scipy.sparse.linalg as spla  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, jit, optional, run_sections, timed_interleaved  # noqa: E402

from ddgjax.mesh import icosphere  # noqa: E402

igl = optional("igl")
fluids = optional("ddgjax.fluids")

# --- the NumPy + SciPy peer ---------------------------------------------------------------------------


def numpy_basis(V, F, k, *, face_block=4096):
    """`dict(values (k,), vectors (nv, k), mass (nv,), advection (k, k, k), V, F)` of the spectral method.

    Eigenpairs by ARPACK's shift-invert Lanczos with `sigma` just below zero (as `ddgjax.spectral`),
    M-orthonormal as `eigsh` returns them. The advection tensor: per face, the basis' constant
    gradients `g` (libigl's `grad`), `J_f(phi_i, phi_j) = n_f . (g_i x g_j) = g_i . (g_j x n_f)`,
    weighted by `area_f` times `phi_k` at the centroid (the mean of its corners: the exact integral
    of a linear function), `W_kij = sum_f area_f phi_k(c_f) J_f(phi_i, phi_j)`; then its totally
    antisymmetric part `(W_kij + W_ijk + W_jki) / 3` (the continuum tensor's symmetry, which makes an
    implicit-midpoint step keep energy and enstrophy). Stored `(i, k, j)` so a step's contraction
    with `b` is one `(k,) @ (k, k^2)` product. Faces in blocks of `face_block` bound the memory of
    the `(faces, k^2)` intermediate.
    """
    L = -igl.cotmatrix(V, F)
    M = igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI)
    sigma = -1e-8 * L.diagonal().sum() / M.diagonal().sum()
    values, vectors = spla.eigsh(L.tocsc(), k=k, M=M.tocsc(), sigma=sigma, which="LM")
    order = np.argsort(values)
    values, vectors = values[order], vectors[:, order]
    nf = F.shape[0]
    grad = igl.grad(V, F)  # (3 nf, nv): all x components, then y, then z
    g = (grad @ vectors).reshape(3, nf, k).transpose(1, 0, 2)  # (nf, 3, k)
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / (2 * area[:, None])
    rotated = np.cross(g, normal[:, :, None], axisa=1, axisb=1, axisc=1)  # g_j x n_f, (nf, 3, k)
    weight = area[:, None] * vectors[F].mean(axis=1)  # (nf, k): area_f phi_k(c_f)
    W = np.zeros((k * k, k))
    for start in range(0, nf, face_block):
        block = slice(start, start + face_block)
        for d in range(3):  # sum_f [area phi_k g_i^d]_f [g_j x n]^d_f, as a (k k, nf) @ (nf, k) product
            left = (weight[block, :, None] * g[block, d, None, :]).reshape(-1, k * k)
            W += left.T @ rotated[block, d]
    W = W.reshape(k, k, k)  # (k, i, j)
    W = (W + W.transpose(1, 2, 0) + W.transpose(2, 0, 1)) / 3
    return {
        "values": values,
        "vectors": vectors,
        "mass": M.diagonal(),
        "advection": np.ascontiguousarray(W.transpose(1, 0, 2)),  # (i, k, j)
        "z": V[:, 2],
    }


def numpy_flow(basis, vorticity, *, tau, steps, save_every, rotation=0.0, viscosity=0.0, rtol=1e-13, max_iterations=100):
    """`dict(vorticity (s, nv), kinetic_energy (s,), enstrophy (s,), iterations)` after `steps` implicit-midpoint steps.

    `a = Phi^T M w`; each step solves `m = a_n + (tau / 2) F(m)` by fixed-point iteration until the
    largest change is at most `rtol` times the largest `|m|`, then `a_{n+1} = 2 m - a_n`.
    `F(a) = -(b @ W)(a + f) - nu lambda a`, `b = -a / lambda` (0 on the constant mode), `f = Phi^T M
    (2 Omega z)`. Kinetic energy `1/2 sum lambda_i b_i^2`, enstrophy `1/2 sum a_i^2`.
    """
    values, vectors, mass, W = basis["values"], basis["vectors"], basis["mass"], basis["advection"]
    k = values.size
    W2 = W.reshape(k, k * k)
    inverse = np.zeros(k)
    inverse[1:] = -1.0 / values[1:]  # the constant mode carries no stream function
    f = vectors.T @ (mass * 2.0 * rotation * basis["z"])
    damping = viscosity * values

    def rate(a):
        return -((inverse * a) @ W2).reshape(k, k) @ (a + f) - damping * a

    a = vectors.T @ (mass * np.asarray(vorticity))
    saved, iterations = [a], 0
    half = 0.5 * tau
    for step in range(1, steps + 1):
        m = a + half * rate(a)
        for _ in range(max_iterations):
            new = a + half * rate(m)
            iterations += 1
            converged = np.abs(new - m).max() <= rtol * np.abs(new).max()
            m = new
            if converged:
                break
        a = 2.0 * m - a
        if step % save_every == 0:
            saved.append(a)
    A = np.array(saved)
    b = A * inverse
    return {
        "vorticity": A @ vectors.T,
        "kinetic_energy": 0.5 * (values * b**2).sum(axis=1),
        "enstrophy": 0.5 * (A**2).sum(axis=1),
        "iterations": iterations,
    }


# --- checks ---------------------------------------------------------------------------------------------


def _verdict(name, value, bound):
    ok = value <= bound
    print(f"- {name}: {value:.2e} (bound {bound:.2g}) {'ok' if ok else 'FAILED'}")
    return ok


def check(args) -> int:
    """The NumPy peer on icosphere(3), k = 64 (the l <= 7 harmonics exactly), and against ddgjax when it imports."""
    mesh = icosphere(3)
    V, F = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    x, y, z = V.T
    basis = numpy_basis(V, F, 64)
    M = basis["mass"]
    ok = True
    print(f"# NumPy peer checks: icosphere(3), {V.shape[0]} vertices, k = 64")

    # invariants: a random smooth vorticity, 500 steps; a multiple of round-off from the solve's tolerance
    rng = np.random.default_rng(0)
    a0 = rng.standard_normal(64) / (1 + basis["values"])
    a0[0] = 0
    run = numpy_flow(basis, basis["vectors"] @ a0, tau=0.05, steps=500, save_every=50)
    energy, enstrophy = run["kinetic_energy"], run["enstrophy"]
    ok &= _verdict("kinetic energy drift (relative, 500 steps)", np.abs(energy / energy[0] - 1).max(), 1e-10)
    ok &= _verdict("enstrophy drift (relative, 500 steps)", np.abs(enstrophy / enstrophy[0] - 1).max(), 1e-10)
    print(f"  (mean fixed-point iterations per step: {run['iterations'] / 500:.1f})")

    # w = x z, an l = 2 harmonic: steady; its turnover time 2 pi / max|u| ~ 2 pi * 6 / 0.5 ~ 75 for unit amplitude.
    # The discrete l = 2 eigenspace (modes 4-8) is exactly degenerate (the icosahedral group's 5-dimensional
    # irreducible representation), so its part of x z is exactly steady; only the spill s^2 = |Q w0|^2 / |w0|^2
    # outside it moves: 1 - correlation <= 2 s^2 (enstrophy kept), and the amplitude is |P_k w0| / |w0|.
    w0 = x * z
    norm0 = (w0 * M * w0).sum()
    spill = 1 - ((basis["vectors"][:, 4:9].T @ (M * w0)) ** 2).sum() / norm0
    steady = numpy_flow(basis, w0, tau=0.5, steps=600, save_every=600)["vorticity"][-1]
    corr = (w0 * M * steady).sum() / np.sqrt(norm0 * (steady * M * steady).sum())
    ok &= _verdict(f"w = x z, 4 turnover times (spill s^2 = {spill:.1e}): 1 - correlation", 1 - corr, 2 * spill)
    ok &= _verdict("w = x z: amplitude change (relative)", abs(np.sqrt((steady**2 * M).sum() / norm0) - 1), spill)

    # Rossby-Haurwitz: w = x z on a sphere turning at Omega about z moves at -2 Omega / (l (l + 1)) = -Omega / 3.
    # A discretisation error O(h^2): under 1e-2 on icosphere(3), and about 4x smaller on icosphere(4).
    errors = []
    for level, level_basis in ((3, basis), (4, None)):
        if level_basis is None:
            fine = icosphere(level)
            Vl = np.asarray(fine.vertices, dtype=np.float64)
            level_basis = numpy_basis(Vl, np.asarray(fine.faces, dtype=np.int64), 64)
        else:
            Vl = V
        xl, yl, zl = Vl.T
        Ml = level_basis["mass"]
        omega, T = 1.0, 3.0
        moved = numpy_flow(level_basis, xl * zl, tau=0.01, steps=300, save_every=300, rotation=omega)["vorticity"][-1]
        angle = np.arctan2((moved * Ml * yl * zl).sum(), (moved * Ml * xl * zl).sum())
        expected = -2 * omega / 6 * T
        errors.append(abs(angle / expected - 1))
        print(f"  Rossby-Haurwitz l = 2, icosphere({level}): angle {angle:.5f} after T = {T}, expected {expected:.5f}")
    ok &= _verdict("Rossby-Haurwitz rate, icosphere(3): relative error", errors[0], 1e-2)
    ok &= _verdict("Rossby-Haurwitz rate, icosphere(4): relative error / icosphere(3)'s", errors[1] / errors[0], 0.35)

    if fluids is None:
        print("- ddgjax.fluids does not import: the comparison is skipped")
        return 0 if ok else 1
    print("# ddgjax against the NumPy peer: vorticity at vertices after 100 steps (relative 2-norm, M-weighted)")
    for rotation, viscosity in ((0.0, 0.0), (1.0, 0.0), (1.0, 1e-3)):
        ours = fluids.euler_flow(
            mesh,
            jnp.asarray(basis["vectors"] @ a0),
            tau=0.05,
            steps=100,
            save_every=100,
            rotation=rotation,
            viscosity=viscosity,
            k=64,
        )
        theirs = numpy_flow(
            basis, basis["vectors"] @ a0, tau=0.05, steps=100, save_every=100, rotation=rotation, viscosity=viscosity
        )
        diff = np.asarray(ours.value) - theirs["vorticity"][-1]
        rel = np.sqrt((diff**2 * M).sum() / (theirs["vorticity"][-1] ** 2 * M).sum())
        ok &= _verdict(f"rotation {rotation}, viscosity {viscosity}", rel, 1e-8)
    return 0 if ok else 1


# --- benchmark ------------------------------------------------------------------------------------------


def compiled(fn, *args):
    """`(fn, compile ms)`: `fn` jitted and compiled ahead of time for `args`."""
    start = time.perf_counter()
    fn.lower(*args).compile()
    return fn, 1e3 * (time.perf_counter() - start)


def initial_vorticity(V, basis_np):
    """A smooth zero-mean vorticity: two opposite Gaussian vortices plus an l = 2 wave (the same for both)."""
    x, y, z = V.T

    def bump(p):
        return np.exp(-((V - np.asarray(p)) ** 2).sum(axis=1) / 0.05)

    w = bump([0.6, 0.0, 0.8]) - bump([-0.6, 0.0, 0.8]) + 0.3 * x * z
    return w - (w * basis_np["mass"]).sum() / basis_np["mass"].sum()


def section_flow(args):
    print(
        f"\n# Euler flow, spectral, k = {args.k}, tau = {args.tau:g}: {args.steps} steps saving every {args.save_every}; "
        f"gradient of sum(c * final vorticity) in the initial vorticity"
    )
    print(
        "| mesh | nv | basis ddgjax (ms) | basis NumPy (ms) | ddgjax / NumPy | flow ddgjax (ms) | flow NumPy (ms) "
        "| steps/s ddgjax / NumPy | speed-up | steps only, steps/s ddgjax / NumPy | speed-up | loss forward (ms) "
        "| value_and_grad (ms) | gradient / forward | compile basis / flow / gradient (s) | max rel diff |"
    )
    print("|" + "---|" * 16)
    for level in args.levels:
        _flow_row(level, args)


def _flow_row(level, args):
    mesh = icosphere(level)
    V, F = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    k, steps, save = args.k, args.steps, args.save_every
    settings = {"tau": args.tau, "steps": steps, "save_every": save, "rotation": args.rotation}

    # bases: one interleaved group (slow calls: a second-long first run counts as a sample)
    numpy_b = None
    calls = {"NumPy basis": (lambda: numpy_basis(V, F, k), ())}
    if fluids is not None:
        build, compile_basis = compiled(jit(lambda v: fluids.fluid_basis(mesh.with_vertices(v), k)), mesh.vertices)
        calls["ddgjax basis"] = (build, (mesh.vertices,))
    times_b, results_b = timed_interleaved(calls, args.repeats, args.budget)
    numpy_b = results_b["NumPy basis"]
    w0 = initial_vorticity(V, numpy_b)
    w0j = jnp.asarray(w0)
    c = jnp.asarray(np.random.default_rng(0).standard_normal(V.shape[0]))

    calls = {
        "NumPy flow": (lambda: numpy_flow(numpy_b, w0, **settings), ()),
        "NumPy steps only": (lambda: numpy_flow(numpy_b, w0, **{**settings, "save_every": steps}), ()),
    }
    if fluids is not None:
        basis = results_b["ddgjax basis"]

        def flow(w, basis, save_every=save):
            return fluids.euler_flow(mesh, w, **{**settings, "save_every": save_every}, k=k, basis=basis).vorticity

        def loss(w, basis):
            return jnp.vdot(c, flow(w, basis, steps)[-1])

        forward, compile_flow = compiled(jit(flow), w0j, basis)
        steps_only, _ = compiled(jit(lambda w, b: flow(w, b, steps)), w0j, basis)
        forward_loss, _ = compiled(jit(loss), w0j, basis)
        gradient, compile_gradient = compiled(jit(jax.value_and_grad(loss)), w0j, basis)
        calls |= {
            "ddgjax flow": (forward, (w0j, basis)),
            "ddgjax steps only": (steps_only, (w0j, basis)),
            "ddgjax loss": (forward_loss, (w0j, basis)),
            "ddgjax value_and_grad": (gradient, (w0j, basis)),
        }
    times, results = timed_interleaved(calls, args.repeats, args.budget)

    def per_second(name):
        return f"{1e3 * steps / times[name][0]:,.0f}"

    line = [f"icosphere({level})", f"{V.shape[0]:,}"]
    if fluids is None:
        line += ["-", fmt(times_b["NumPy basis"], args.repeats), "-", "-", fmt(times["NumPy flow"], args.repeats)]
        line += [f"- / {per_second('NumPy flow')}", "-", f"- / {per_second('NumPy steps only')}"] + ["-"] * 6
    else:
        ours, theirs = np.asarray(results["ddgjax flow"]), results["NumPy flow"]["vorticity"]
        diff = np.abs(ours - theirs).max() / np.abs(theirs).max()
        line += [
            fmt(times_b["ddgjax basis"], args.repeats),
            fmt(times_b["NumPy basis"], args.repeats),
            f"{times_b['ddgjax basis'][0] / times_b['NumPy basis'][0]:.2f}x",
            fmt(times["ddgjax flow"], args.repeats),
            fmt(times["NumPy flow"], args.repeats),
            f"{per_second('ddgjax flow')} / {per_second('NumPy flow')}",
            f"{times['NumPy flow'][0] / times['ddgjax flow'][0]:.2f}x",
            f"{per_second('ddgjax steps only')} / {per_second('NumPy steps only')}",
            f"{times['NumPy steps only'][0] / times['ddgjax steps only'][0]:.2f}x",
            fmt(times["ddgjax loss"], args.repeats),
            fmt(times["ddgjax value_and_grad"], args.repeats),
            f"{times['ddgjax value_and_grad'][0] / times['ddgjax loss'][0]:.2f}x",
            f"{compile_basis / 1e3:.1f} / {compile_flow / 1e3:.1f} / {compile_gradient / 1e3:.1f}",
            f"{diff:.1e}",
        ]
    print("| " + " | ".join(line) + " |")
    print(f"  (NumPy: {results['NumPy flow']['iterations'] / steps:.1f} fixed-point iterations per step)")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="verify the NumPy peer (and ddgjax against it), then stop")
    parser.add_argument(
        "--levels", default="5", help="icosphere levels, comma-separated: 5 (10,242 vertices), 7 (163,842: minutes)"
    )
    parser.add_argument("--k", type=int, default=64)
    parser.add_argument("--tau", type=float, default=0.01)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--save-every", type=int, default=100, dest="save_every")
    parser.add_argument("--rotation", type=float, default=1.0, help="Omega: the frame's angular velocity about +z")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--budget", type=float, default=20.0, help="seconds of runs per call, after which it stops repeating")
    args = parser.parse_args(argv)
    if igl is None:
        print("libigl is needed for the NumPy peer: pip install libigl")
        return 1
    if args.check:
        return check(args)
    args.levels = [int(level) for level in args.levels.split(",")]
    args.sections = "flow"
    run_sections({"flow": section_flow}, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
