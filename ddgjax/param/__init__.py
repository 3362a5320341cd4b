r"""Surface parametrisation of disk-topology meshes, differentiable in the vertex positions.

- Fixed boundary: `tutte_embedding` (uniform or cotan `weights=`, the boundary on a `shape=`: a circle,
  a square or given positions) and `harmonic_map` (cotan weights).
- Free boundary, conformal: `lscm` (least squares conformal maps, two `fixed_vertices=` pinned),
  `spectral_conformal_map` (no pins: the smallest non-trivial eigenvector of the conformal energy),
  `conformal_energy_matrix` (the `2 nv x 2 nv` quadratic form $E_C = E_D - \mathcal{A}$ both minimise).
- `boundary_first_flattening`: conformal maps with prescribed boundary scale factors or boundary
  angles (Sawhney & Crane 2017), or a `shape=`: the flat disk (`"circle"`) or a rectangle layout.
- `map_distortion` -> `MapDistortion`: per-face area ratio, quasi-conformal distortion, conformal
  energy and flips of any map, with summaries.

Every map returns `(nv, 2)` positions and refuses a mesh that is not a topological disk with
`ddgjax.DDGInputError`; its sparse solves take `solver=` (`ddgjax.LINEAR_SOLVERS`) and it reports
their outcome (`throw=True` raises, `throw=False` returns a `ddgjax.Solution`). Conventions: the boundary loop is `mesh.topology.boundary_loops[0]` and every
per-boundary-vertex argument follows its order; unreferenced vertices go to the origin.

The conformal energy is the Dirichlet energy less the signed area of the map $(u, v)$:

$$E_C(u, v) = E_D(u, v) - \mathcal{A}(u, v) = \tfrac12 x^\top Q x, \qquad E_D = \tfrac12 (u^\top L u + v^\top L v), \qquad x = [u; v]$$
"""

from ._bff import boundary_first_flattening as boundary_first_flattening
from ._distortion import MapDistortion as MapDistortion
from ._distortion import map_distortion as map_distortion
from ._lscm import conformal_energy_matrix as conformal_energy_matrix
from ._lscm import lscm as lscm
from ._lscm import spectral_conformal_map as spectral_conformal_map
from ._tutte import harmonic_map as harmonic_map
from ._tutte import tutte_embedding as tutte_embedding
