r"""The screened system of a reconstruction's grid, and the geometric multigrid V-cycle that preconditions it.

The screening correction `delta` (`_indicator`) minimises a finite-difference Dirichlet energy plus the
screening term at the points,

$$E(\delta) = \tfrac12 \delta^\top L_h \delta + \tfrac{w}{2} \sum_i \big(s_i^\top \delta - r_i\big)^2,
\qquad A = L_h + w S^\top S,$$

with `L_h` the 7-point Laplacian over `h^2` and `s_i` the trilinear weights of point `i` (the rows of `S`).
The grid is stored flat (node `(a, b, c)` at `(a N + b) N + c`) and `L_h` couples the flat offsets
`+-1, +-N, +-N^2`: the periodic grid's stencil, except that across the faces of the second and third
axes it wraps to the next line (a helical boundary). It is still the Laplacian of a connected graph
(symmetric positive semidefinite, constants its kernel), the points stay `(scale - 1) / 2` of their
extent away from those faces, and the stencil is one fused pass instead of three rolls of a 3-D array.

`A` is badly conditioned for a spectral preconditioner: `w S^T S` is large on the band of nodes around
the points and zero elsewhere, so a shift that suits the band does not suit the rest
(benchmarks/README.md, "Poisson reconstruction"). A V-cycle fits both:

- levels `N, N/2, ..., 8`; on the coarse ones `A_l = L_{2^l h} + diag(d_l)`, `d_{l+1} = P^T d_l / 8`,
  with `d_0 = w S^T 1` the lumped screening (row sums of `w S^T S`, since the weights of a point sum
  to 1) and `P` trilinear interpolation (so `A_{l+1}` is the lumped Galerkin `P^T A_l P / 8`);
- one damped Jacobi sweep before and after the coarse correction, `D = 6 / h^2 + d` (`w S^T S` is at
  most its lumped diagonal, so `D^{-1} A` has eigenvalues at most 2 and `omega = 0.8` smooths);
- a Cholesky solve on the coarsest level (`8^3` nodes).

The cycle is a fixed symmetric linear map, so it preconditions conjugate gradients.

Reference: W. L. Briggs, V. E. Henson, S. F. McCormick, "A Multigrid Tutorial", 2nd ed., SIAM 2000
(V-cycles, damped Jacobi, full weighting); M. Kazhdan, H. Hoppe, "Screened Poisson Surface
Reconstruction", ACM TOG 32(3), 2013 (the screened system, solved by multigrid on an octree).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

#: The damping of the Jacobi smoother: below 1, since the largest eigenvalue of `D^{-1} A` is at most 2.
JACOBI_DAMPING = 0.8

#: The nodes per axis of the coarsest level, solved directly (`8^3` unknowns).
COARSEST = 8

#: The V-cycle runs in single precision whatever the system's: it only has to approximate `A^{-1}`, and it
#: is most of a step's memory traffic (the conjugate gradients around it stay in the system's precision).
CYCLE_DTYPE = jnp.float32


def grid_laplacian(x, n: int, spacing):
    """`L_h x` for the flat `(n^3,)` node values `x`: the 7-point stencil over `h^2` (module docstring)."""
    total = 6.0 * x
    for offset in (1, n, n * n):
        total = total - jnp.roll(x, offset) - jnp.roll(x, -offset)
    return total / (spacing * spacing)


def prolong(coarse):
    """`P c`: the trilinear interpolation of the periodic `(m, m, m)` grid `coarse` to `(2m, 2m, 2m)`."""
    for axis in range(3):
        midpoints = 0.5 * (coarse + jnp.roll(coarse, -1, axis))
        coarse = jnp.stack([coarse, midpoints], axis=axis + 1)
        shape = list(coarse.shape)
        shape[axis : axis + 2] = [shape[axis] * 2]
        coarse = coarse.reshape(shape)
    return coarse


def restrict(fine):
    """`P^T f / 8`: full weighting of the periodic `(2m, 2m, 2m)` grid `fine` to `(m, m, m)` (the transpose of
    `prolong`, scaled so that constants stay constant)."""
    for axis in range(3):
        shape = list(fine.shape)
        shape[axis : axis + 1] = [shape[axis] // 2, 2]
        pairs = fine.reshape(shape)
        even, odd = jnp.take(pairs, 0, axis=axis + 1), jnp.take(pairs, 1, axis=axis + 1)
        fine = 0.5 * even + 0.25 * (odd + jnp.roll(odd, 1, axis))
    return fine


def screened_system(flat, weights, screening_weight, n: int, spacing):
    """`(operator, preconditioner)` of the screened system `A = L_h + w S^T S` on the flat `(n^3,)` grid.

    `flat`, `weights` `(m, 8)` are the points' cell corners and trilinear weights (`cell_corners`, padding weighted
    0), `screening_weight` is `w`. The preconditioner is one V-cycle (module docstring); it is built from values
    held constant under differentiation (only the operator's derivative enters the implicit gradient).
    """
    corners = flat.reshape(-1)

    def screened(weights, screening_weight, spacing):
        def operator(x):
            at_points = jnp.sum(weights * x[flat], axis=-1)
            screening = screening_weight * (weights * at_points[:, None]).reshape(-1)
            return grid_laplacian(x, n, spacing).at[corners].add(screening)

        return operator

    fixed = jax.lax.stop_gradient((weights, screening_weight, spacing))
    fixed_weights, fixed_screening, fixed_spacing = (jnp.asarray(value, CYCLE_DTYPE) for value in fixed)
    fixed_operator = screened(fixed_weights, fixed_screening, fixed_spacing)
    lumped = jnp.zeros(n**3, CYCLE_DTYPE).at[corners].add(fixed_screening * fixed_weights.reshape(-1))
    levels = [(n, fixed_spacing, lumped)]
    while levels[-1][0] > COARSEST:
        size, step, diagonal = levels[-1]
        levels.append((size // 2, 2 * step, restrict(diagonal.reshape(size, size, size)).reshape(-1)))

    def level_operator(level, x):
        size, step, diagonal = levels[level]
        return fixed_operator(x) if level == 0 else grid_laplacian(x, size, step) + diagonal * x

    coarsest = len(levels) - 1
    size = levels[-1][0]
    dense = jax.vmap(lambda unit: level_operator(coarsest, unit))(jnp.eye(size**3, dtype=CYCLE_DTYPE))
    factor = jax.scipy.linalg.cho_factor(dense)

    def cycle(level, b):
        if level == coarsest:
            return jax.scipy.linalg.cho_solve(factor, b)
        size, step, diagonal = levels[level]
        smoother = JACOBI_DAMPING / (6.0 / (step * step) + diagonal)
        x = smoother * b
        residual = (b - level_operator(level, x)).reshape(size, size, size)
        x = x + prolong(cycle(level + 1, restrict(residual).reshape(-1)).reshape((size // 2,) * 3)).reshape(-1)
        return x + smoother * (b - level_operator(level, x))

    def preconditioner(r):
        return cycle(0, r.astype(CYCLE_DTYPE)).astype(r.dtype)

    return screened(weights, screening_weight, spacing), preconditioner
