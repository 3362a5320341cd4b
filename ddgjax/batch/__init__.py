r"""Batches of triangle meshes of different sizes: padded to bucketed shapes, with per-mesh operators.

- `MeshBatch.from_meshes(meshes)`: padded `(B, nvp, 3)` vertices and `(B, nfp, 3)` faces with masks,
  per-mesh counts and the index plan of the operators, all arrays with the batch axis first, so
  batches of one bucket (`bucket`) share one compiled program and shard along axis 0
  (`ddgjax.sharding.shard_batch`); `packed()`, `meshes()`, `unpad(...)` go back to per-mesh data;
  `pad_vertex_values(list)` pads per-mesh values.
- Batched operators, each equal per mesh to its single-mesh namesake: `laplacian_apply`,
  `dirichlet_energy`, `lumped_mass` (the lumped mass matrix's diagonal), `mass_apply`, `face_areas`,
  `face_normals`, `vertex_normals`, `gradient`. Differentiable, jit / vmap, zero on padding.

Each mesh of the batch keeps its own operators, e.g. its PSD cotan Laplacian

$$\sum_j L_{ij} u_j = \tfrac12 \sum_{j \sim i} (\cot\alpha_{ij} + \cot\beta_{ij})(u_i - u_j).$$
"""

from ._batch import MeshBatch as MeshBatch
from ._batch import PackedMeshes as PackedMeshes
from ._batch import pad_vertex_values as pad_vertex_values
from ._batch import require_batch as require_batch
from ._batch import unpad as unpad
from ._bucket import bucket as bucket
from ._operators import dirichlet_energy as dirichlet_energy
from ._operators import face_areas as face_areas
from ._operators import face_normals as face_normals
from ._operators import gradient as gradient
from ._operators import laplacian_apply as laplacian_apply
from ._operators import lumped_mass as lumped_mass
from ._operators import mass_apply as mass_apply
from ._operators import vertex_normals as vertex_normals
