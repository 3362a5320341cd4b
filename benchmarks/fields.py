"""Smoothest cross fields: ddgjax side by side with the same solve in SciPy, one process.

Section **smoothest** (the only one): the globally smoothest 4-direction (cross) field of a mesh, the
eigenvector of the smallest eigenvalue of `A u = lambda M u` (`A` the connection Laplacian for
`n = 4`, `M` the Voronoi mass; Knoeppel et al. 2013), on a few meshes of `../shared/meshes` and an
icosphere of ~100k faces:

- ddgjax `smoothest_field(mesh, n=4).field` (jitted in the vertex positions: assembly, real form,
  `smallest_eigenpairs(k=2, hermitian_real_form=True)`, i.e. complex ARPACK shift-invert on the
  host, phase fix), and its value and gradient (the energy, the smallest eigenvalue, as loss);
- SciPy, the same complex Hermitian matrices assembled in NumPy from ddgjax's transport angles and
  cotan weights (geometry taken as given, so only the solve is compared): `eigsh(A, k=1, M,
  sigma, which="LM", v0)` on the complex matrix (shift-invert with a complex SuperLU; the same
  deterministic start as ddgjax's, so both do the same iterations), and with `--inverse-iteration`
  an inverse power iteration with one complex `splu` of `A - sigma M` (stopped at a relative
  eigen-residual of 1e-10).

Target: ddgjax's field no slower than SciPy's eigsh. Times: min / median ms over interleaved repeats
(`benchmarks/solve.py`'s `timed_interleaved`). Run:
`python benchmarks/fields.py [--meshes spot.obj,double-torus.obj,icosphere(6)] [--repeats 5]`.
"""

from __future__ import annotations

import pathlib
import sys

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, jit, mesh_sections_parser, run_sections, timed_interleaved, warmed  # noqa: E402

from ddgjax.fields import connection_mass_matrix, edge_transport_angles, smoothest_field  # noqa: E402
from ddgjax.io import load_mesh  # noqa: E402
from ddgjax.mesh import edge_cotan_weights, icosphere  # noqa: E402

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "meshes"
N = 4


def meshes(names):
    """`{name: mesh}`: icospheres by subdivision (`icosphere(6)`), or files in ../shared/meshes."""
    return {
        name: icosphere(int(name[len("icosphere(") : -1])) if name.startswith("icosphere(") else load_mesh(SHARED / name)
        for name in names
    }


def scipy_matrices(mesh):
    """The connection Laplacian (n = 4) and the Voronoi mass as SciPy CSC matrices, assembled in NumPy."""
    edges = np.asarray(mesh.edges)
    w = np.asarray(edge_cotan_weights(mesh))
    rotation = np.exp(-1j * N * np.asarray(edge_transport_angles(mesh)))
    nv = mesh.n_vertices
    diagonal = np.bincount(edges.ravel(), weights=np.repeat(w, 2), minlength=nv)
    rows = np.concatenate([np.arange(nv), edges[:, 0], edges[:, 1]])
    cols = np.concatenate([np.arange(nv), edges[:, 1], edges[:, 0]])
    values = np.concatenate([diagonal, -w * rotation, -w * np.conj(rotation)])
    A = sp.csc_matrix((values, (rows, cols)), shape=(nv, nv))
    M = sp.diags(np.asarray(connection_mass_matrix(mesh).values)).tocsc().astype(complex)
    return A, M


def scipy_eigsh(A, M, shift):
    start = (np.ones(A.shape[0]) + np.linspace(0.0, 1.0, A.shape[0])) * (1 + 0.5j)  # ddgjax's start vector
    values, vectors = spla.eigsh(A, k=1, M=M, sigma=shift, which="LM", v0=start, tol=0.0)
    return values[0], vectors[:, 0]


def scipy_inverse_iteration(A, M, shift, tolerance=1e-10, max_steps=1000):
    """Inverse power iteration with one SuperLU factorisation of `A - shift M`."""
    lu = spla.splu((A - shift * M).tocsc())
    u = np.ones(A.shape[0], dtype=complex)
    for _ in range(max_steps):
        u = lu.solve(M @ u)
        u /= np.sqrt(np.vdot(u, M @ u).real)
        energy = np.vdot(u, A @ u).real
        if np.linalg.norm(A @ u - energy * (M @ u)) <= tolerance * energy * np.linalg.norm(M @ u):
            break
    return energy, u


def section_smoothest(args):
    print(f"\n# the smoothest {N}-direction field: smallest eigenpair of A u = lambda M u (Voronoi mass)")
    for name, mesh in meshes(args.meshes).items():
        _smoothest_on(name, mesh, args)


def _smoothest_on(name, mesh, args):
    A, M = scipy_matrices(mesh)
    shift = -1e-8 * A.diagonal().real.sum() / M.diagonal().real.sum()
    ours = jit(lambda V: smoothest_field(mesh.with_vertices(V), n=N).field)
    energy_and_gradient = jit(jax.value_and_grad(lambda V: smoothest_field(mesh.with_vertices(V), n=N).energy))
    calls = {
        "ddgjax smoothest_field (jit)": (ours, (mesh.vertices,)),
        "scipy eigsh (complex, shift-invert)": (lambda: scipy_eigsh(A, M, shift), ()),
        "ddgjax value and gradient of the energy": (energy_and_gradient, (mesh.vertices,)),
    }
    if args.inverse_iteration:
        calls["scipy inverse iteration (complex splu)"] = (lambda: scipy_inverse_iteration(A, M, shift), ())
    times, results = timed_interleaved(warmed(calls), args.repeats, args.budget)
    expected = results["scipy eigsh (complex, shift-invert)"][0]
    error = abs(float(smoothest_field(mesh, n=N).energy) - expected) / expected
    reference = times["ddgjax smoothest_field (jit)"][0]
    print(
        f"\n## {name}: nv = {mesh.n_vertices}, nf = {mesh.n_faces}  (min / median ms; ratio to ddgjax's field)  "
        f"eigenvalues agree to {error:.1e}"
    )
    for row, t in times.items():
        print(f"  {row:48s} {fmt(t, args.repeats):>24s} {t[0] / reference:7.2f}x")


SECTIONS = {"smoothest": section_smoothest}


def main(argv=None) -> int:
    parser = mesh_sections_parser(
        __doc__.splitlines()[0], SECTIONS, "spot.obj,double-torus.obj,kitten.obj,icosphere(6)", budget=20.0
    )
    parser.add_argument("--inverse-iteration", action="store_true", help="also time SciPy inverse iteration (slow)")
    run_sections(SECTIONS, parser.parse_args(argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
