r"""Shape correspondence by functional maps, differentiable in the descriptors.

A pipeline in the bases of two `SpectralShape`s (`spectral_shape(mesh, k)`: lumped mass, `k`
eigenpairs), source and target:

- `descriptors(shape, kind="wks")`: wave or heat kernel signatures (Aubry et al. 2011; Sun et al.
  2009), multiscale, each column normalised to unit M-norm as pyFM does;
- `functional_map(source, target, source_descriptors, target_descriptors, ...)`: the `(k_t, k_s)`
  least-squares functional map (Ovsjanikov et al. 2012) with descriptor preservation, Laplacian
  commutativity, descriptor commutativity and the orientation-aware term of Ren et al. 2018 that
  tells a shape from its mirror image; one linear solve, differentiable in the descriptors (the
  functional-map layer of deep functional maps);
- `point_map(C, source, target)`: for each target vertex its source vertex, by nearest neighbours in
  the spectral embedding; `functional_map_from_point_map` the way back;
- `icp_refine` and `zoomout_refine` (Melzi et al. 2019): refinements of a functional map;
- `match_shapes(source_mesh, target_mesh)`: the whole pipeline with good defaults, a `MatchResult`
  with `.point_map` and `.functional_map`;
- `geodesic_error(...)`: the mean geodesic error of a point map against ground truth, normalised by the
  square root of the area (Kim et al. 2011's protocol).

Conventions as pyFM (`pyfmaps`): `C` maps source functions to target functions, a point map lists
each target vertex's source vertex.

The map $C$ takes spectral coefficients of the source to those of the target; at its core it fits the
descriptors' coefficients $A$ (source) and $B$ (target) in the least-squares sense, with the Laplacian
commutativity term:

$$\min_C \ \lVert C A - B \rVert^2 + \mu \lVert C \Lambda_s - \Lambda_t C \rVert^2.$$
"""

from ._descriptors import descriptors as descriptors
from ._evaluate import geodesic_error as geodesic_error
from ._functional_map import functional_map as functional_map
from ._match import MatchResult as MatchResult
from ._match import match_shapes as match_shapes
from ._point_map import functional_map_from_point_map as functional_map_from_point_map
from ._point_map import point_map as point_map
from ._refine import icp_refine as icp_refine
from ._refine import zoomout_refine as zoomout_refine
from ._shape import SpectralShape as SpectralShape
from ._shape import spectral_shape as spectral_shape
