r"""Discrete exterior calculus on triangle meshes.

Discrete k-forms are arrays of integrals over k-simplices: 0-forms `(nv,)` on vertices, 1-forms
`(ne,)` on the edges of `mesh.edges` (run from the lower to the higher vertex index), 2-forms `(nf,)`
on faces (oriented by the face's vertex order). `d0`, `d1` and the diagonal Hodge stars are fixed-
pattern `SparseMatrix`es whose values re-assemble under jit for moved vertices; everything else is a
pure function of the vertex positions (jit, grad, vmap).

Which mesh each operator accepts (`MeshDataError` otherwise, naming the operator and the first
offending edges):

- any triangle mesh (non-manifold, non-orientable, with unreferenced vertices): `d0`, `hodge0`,
  `hodge1`, `integrate_0form`, `integrate_1form`, `flat`, `sharp`, `gradient` (assembled: `gradient_matrix`), `divergence`,
  `codifferential(degree=1)`, `hodge_laplacian0`. These only use edges with
  their global low -> high orientation, or per-face quantities that do not depend on the face order.
- consistently oriented faces (edge-manifold, every interior edge run in opposite directions by its
  two faces; boundaries allowed): everything that produces or consumes 2-forms or a sense of
  rotation: `d1`, `hodge2`, `integrate_2form`, `curl`, `codifferential(degree=2)`,
  `hodge_laplacian1`, `hodge_laplacian2`.

Dual mesh: the Hodge stars, the codifferential and the Hodge Laplacians take the keyword-only
`dual=`, with the same choices and default as the dual areas and pointwise curvatures of
`ddgjax.mesh`:

- `"voronoi"` (default): `*0` is the mixed area of Meyer et al. 2003 (never negative; libigl's
  Voronoi mass matrix, `ddgjax.laplacian.mass_matrix`'s default), `*1` the circumcentric cotan
  ratio, so `d0^T *1 d0 = L` with the mass matrix libigl pairs with it;
- `"circumcentric"`: the DEC dual of Desbrun et al. 2005, `*1` the same cotan ratio, `*0` the
  circumcentric dual area (negative next to obtuse faces);
- `"barycentric"`: `*0` a third of each incident face, `*1` through the face barycentres (both
  never negative; the DDG exercises' `hodge0` and gpytoolbox `dec_h0`).

The default is the dual without negative areas that the rest of ddgjax uses; pass `dual=` to match a
reference that uses another (the DDG exercises' `*0` is barycentric).

Sign conventions (DESIGN.md): `(d0 u)_e = u[head] - u[tail]`; $d_0^\top \star_1 d_0 = L$, the PSD cotan
Laplacian (Voronoi and circumcentric duals); the codifferential is the adjoint of `d`
($\delta_k = \star_{k-1}^{-1} d_{k-1}^\top \star_k$), so the weak Hodge Laplacians are symmetric, and PSD wherever
the stars are positive (always for the barycentric dual; for the others on Delaunay meshes);
`divergence(gradient(u)) = -L u`.
Degenerate (zero-area) faces contribute nothing and keep values and gradients finite; zero star entries invert to zero.

$$L = d_0^\top \star_1 d_0, \qquad \delta_k = \star_{k-1}^{-1} d_{k-1}^\top \star_k, \qquad \Delta_k = d\,\delta + \delta\, d.$$

Reference: Crane, de Goes, Desbrun, Schroeder, *Digital Geometry Processing with Discrete Exterior
Calculus* (SIGGRAPH course 2013); Desbrun, Hirani, Leok, Marsden, *Discrete Exterior Calculus* (2005).
"""

from ._forms import flat as flat
from ._forms import integrate_0form as integrate_0form
from ._forms import integrate_1form as integrate_1form
from ._forms import integrate_2form as integrate_2form
from ._forms import sharp as sharp
from ._gradient_matrix import gradient_matrix as gradient_matrix
from ._hodge import edge_dual_length_ratios as edge_dual_length_ratios
from ._hodge import hodge0 as hodge0
from ._hodge import hodge1 as hodge1
from ._hodge import hodge2 as hodge2
from ._hodge import hodge_star_entries as hodge_star_entries
from ._operators import d0 as d0
from ._operators import d1 as d1
from ._vector_calculus import codifferential as codifferential
from ._vector_calculus import curl as curl
from ._vector_calculus import divergence as divergence
from ._vector_calculus import gradient as gradient
from ._vector_calculus import hodge_laplacian0 as hodge_laplacian0
from ._vector_calculus import hodge_laplacian1 as hodge_laplacian1
from ._vector_calculus import hodge_laplacian2 as hodge_laplacian2
