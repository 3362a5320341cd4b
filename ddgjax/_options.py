"""The values of the options that recur across ddgjax, each listed once (docs/conventions.md).

Every public function that takes one of these choices takes it under the same keyword, accepts the
same values and checks it with the validator here, so the message a user gets for a bad value is the
same everywhere. A function that cannot honour one of the values (e.g. a lumped-only operator asked
for `mass="galerkin"`) says so in its docstring and refuses it with `check_choice` on its subset.
"""

from __future__ import annotations

from ._errors import check_choice

MASS_MATRICES = ("voronoi", "barycentric", "galerkin")
"""`mass=`: the mass matrix. Lumped mixed-Voronoi (Meyer et al. 2003, libigl's default), lumped
barycentric (a third of each face to each corner) and the full Galerkin (FEM) mass matrix."""

LUMPED_MASS_MATRICES = ("voronoi", "barycentric")
"""The diagonal members of `MASS_MATRICES`: what an operator that divides by vertex areas accepts."""

DUAL_CELLS = ("voronoi", "circumcentric", "barycentric")
"""`dual=`: the dual cell of a vertex (and the dual edge) in DEC and in pointwise curvatures: mixed
Voronoi, the plain circumcentric dual (may be negative on obtuse triangles), barycentric."""

LAPLACIAN_WEIGHTS = ("uniform", "cotan")
"""`weights=`: the edge weights of a graph-style Laplacian (`w_ij = 1`, or the cotan weights)."""

BOUNDARY_CONDITIONS = ("neumann", "dirichlet")
"""`boundary=`: the boundary condition of a PDE on a surface with boundary. (The heat method adds
`"average"`, the mean of the two, as Crane et al. 2013 recommend.)"""

LINEAR_SOLVERS = ("auto", "cholesky", "superlu", "cg", "pyamg")
"""`solver=` everywhere, `ddgjax.solve.linear_solve` and `factorize` included: the backend of the
sparse linear solves (`ddgjax.solve`)."""


def check_mass(mass: str, allowed: tuple[str, ...] = MASS_MATRICES) -> str:
    """`mass` if it is one of `allowed` (default every `MASS_MATRICES`), else `DDGInputError`."""
    return check_choice("mass", mass, allowed)


def check_weights(weights: str) -> str:
    """`weights` if it is one of `LAPLACIAN_WEIGHTS`, else `DDGInputError`."""
    return check_choice("weights", weights, LAPLACIAN_WEIGHTS)


def check_solver(solver: str) -> str:
    """`solver` if it is one of `LINEAR_SOLVERS`, else `DDGInputError`."""
    return check_choice("solver", solver, LINEAR_SOLVERS)
