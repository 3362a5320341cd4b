r"""Operators for learning on meshes: what a diffusion network precomputes per shape, and its layers' operations.

- `diffusion_operators(mesh, k, *, mass="voronoi", robust=True, cache_dir=None, throw=True)` ->
  `DiffusionOperators(mass, values, vectors, frames, gradient_neighbors, gradient_weights)`: the lumped
  mass, the `k` smallest eigenpairs of `L phi = lambda M phi`, vertex tangent frames and the spatial
  gradient as a fixed-degree table of weights (DiffusionNet's `get_operators`), differentiable,
  robust to bad meshes (intrinsic Delaunay) and cached on disk by content (`cache_dir=`);
  `diffusion_operators_of_meshes(meshes, k, ..., progress=True)` for a dataset.
- `stack_diffusion_operators(operators, *, n_vertices=None, degree=None)`: a batch of meshes of
  different sizes, padded to `ddgjax.batch.bucket` sizes; `jax.vmap` the operations below over it.
- `spectral_diffusion(x, operators, times)`: $\Phi \operatorname{diag}(e^{-\lambda t_c}) \Phi^\top M x_c$ per channel.
- `spatial_gradients(x, operators)` -> `(nv, C, 2)` tangent gradients;
  `spatial_gradient_features(gradients, a_real, a_imag)`: $\tanh(\mathrm{Re}(\bar g \, (A g)))$, rotation invariant.
- `DiffusionNetBlock`, `DiffusionNet`: the network built from them with equinox, a worked example
  (`notebooks/11_learning.ipynb` trains one on a batch of meshes of different sizes).

Reference: Sharp, Attaiki, Crane, Ovsjanikov, "DiffusionNet: Discretization Agnostic Learning on
Surfaces" (ACM TOG 2022).

$$L\phi_i = \lambda_i M\phi_i, \qquad h_t(x) = \Phi \operatorname{diag}(e^{-\lambda t}) \Phi^\top M x$$
"""

from ._diffusion import spatial_gradient_features as spatial_gradient_features
from ._diffusion import spatial_gradients as spatial_gradients
from ._diffusion import spectral_diffusion as spectral_diffusion
from ._network import MIN_TIME as MIN_TIME
from ._network import DiffusionNet as DiffusionNet
from ._network import DiffusionNetBlock as DiffusionNetBlock
from ._operators import CACHE_FORMAT_VERSION as CACHE_FORMAT_VERSION
from ._operators import DiffusionOperators as DiffusionOperators
from ._operators import diffusion_operators as diffusion_operators
from ._operators import diffusion_operators_of_meshes as diffusion_operators_of_meshes
from ._stack import stack_diffusion_operators as stack_diffusion_operators
