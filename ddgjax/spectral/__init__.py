"""Spectral geometry: the smallest eigenpairs of the Laplacian, differentiable in the vertex positions.

- `eigenpairs(mesh, k, *, mass="voronoi", boundary="neumann" | "dirichlet")`: the `k` smallest
  eigenpairs of `L phi = lambda M phi` (the discrete `-Delta phi = lambda phi`), M-orthonormal, with
  a deterministic sign.
- `smallest_eigenpairs(L, M, k)`: the same for any sparse generalised symmetric problem, by ARPACK's
  shift-invert Lanczos on the host (inside `jit` through a callback), differentiable (`custom_vjp`)
  in both matrices' values: eigenvalues always, eigenvectors away from clusters of equal
  eigenvalues, and every function invariant within a cluster.
- On an eigenbasis: `spectral_coefficients`, `spectral_reconstruction`, `spectral_filter`,
  `heat_kernel`, `heat_kernel_signature`.
"""

from ._generalized import smallest_eigenpairs as smallest_eigenpairs
from ._laplacian import eigenpairs as eigenpairs
from ._laplacian import heat_kernel as heat_kernel
from ._laplacian import heat_kernel_signature as heat_kernel_signature
from ._laplacian import spectral_coefficients as spectral_coefficients
from ._laplacian import spectral_filter as spectral_filter
from ._laplacian import spectral_reconstruction as spectral_reconstruction
