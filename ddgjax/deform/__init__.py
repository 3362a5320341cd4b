r"""Surface deformation from handles, differentiable in the handles' positions and in the rest shape.

- `biharmonic_deformation(mesh, *, fixed_vertices, fixed_values, order=2)`: k-harmonic deformation, the
  displacement minimising $D^\top L (M^{-1} L)^{k-1} D$ with the handles' displacements prescribed
  (`k = 1` harmonic, `2` biharmonic, `3` triharmonic; Jacobson et al. 2010, Botsch & Sorkine 2008);
  one sparse solve, differentiated implicitly. libigl: `V + igl.harmonic(V, F, b, bc - V[b], k)`.
- `arap(mesh, *, fixed_vertices, fixed_values, ...)`: as-rigid-as-possible surface modelling (Sorkine
  & Alexa 2007, the spokes energy), local-global iterations with one kept factorisation,
  differentiated through its optimality condition.

$$E_\mathrm{ARAP}(V', R) = \sum_i \sum_{j \in N(i)} w_{ij} \lVert (v'_i - v'_j) - R_i (v_i - v_j) \rVert^2, \qquad \min_D \operatorname{tr}\bigl(D^\top L (M^{-1} L)^{k-1} D\bigr)$$

Handles follow the vocabulary of docs/conventions.md (`fixed_vertices=`, `fixed_values=` the new
positions); failures are reported through `ddgjax.RESULTS` (`throw=`).
"""

from ._arap import arap as arap
from ._harmonic import biharmonic_deformation as biharmonic_deformation
