r"""Spectral geometry: the smallest eigenpairs of the Laplacian, differentiable in the vertex positions.

`eigenpairs` takes a tetrahedral `ddgjax.volume.TetMesh` too (the spectrum of a solid; `boundary="dirichlet"`
holds its boundary surface's vertices at 0).

- `eigenpairs(mesh, k, *, mass="voronoi", boundary="neumann" | "dirichlet", throw=True)`: the `k`
  smallest eigenpairs of $L\phi = \lambda M\phi$ (the discrete $-\Delta\phi = \lambda\phi$),
  M-orthonormal, with a deterministic sign, as `Eigenpairs(values, vectors)` (a named tuple).
- `smallest_eigenpairs(L, M, k)`: the same for any sparse generalised symmetric problem, by ARPACK's
  shift-invert Lanczos on the host (inside `jit` through a callback), differentiable (`custom_vjp`)
  in both matrices' values: eigenvalues always, eigenvectors away from clusters of equal
  eigenvalues, and every function invariant within a cluster. A failed eigensolve is
  `ddgjax.RESULTS.eigensolver_failed` (`throw=False` returns a `ddgjax.Solution`).
- On an eigenbasis: `spectral_coefficients`, `spectral_reconstruction`, `spectral_filter(..., response=)`,
  `heat_kernel(values, vectors, sources, t=)`, `heat_kernel_signature(values, vectors, t=)`,
  `wave_kernel_signature(values, vectors, n_energies=100)` (Aubry et al. 2011, pyFM's `auto_WKS`).

The eigenproblem, with `L` the PSD cotan Laplacian and `M` the mass matrix, and the heat kernel on its eigenbasis:

$$L\phi_i = \lambda_i M\phi_i, \quad \phi_i^\top M \phi_j = \delta_{ij}, \qquad k_t(x, y) = \sum_i e^{-\lambda_i t} \phi_i(x) \phi_i(y).$$
"""

from ._generalized import EIGENSOLVERS as EIGENSOLVERS
from ._generalized import Eigenpairs as Eigenpairs
from ._generalized import smallest_eigenpairs as smallest_eigenpairs
from ._laplacian import eigenpairs as eigenpairs
from ._laplacian import heat_kernel as heat_kernel
from ._laplacian import heat_kernel_signature as heat_kernel_signature
from ._laplacian import spectral_coefficients as spectral_coefficients
from ._laplacian import spectral_filter as spectral_filter
from ._laplacian import spectral_reconstruction as spectral_reconstruction
from ._laplacian import wave_kernel_signature as wave_kernel_signature
