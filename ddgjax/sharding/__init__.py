r"""Scale-out across devices and hosts with JAX's own sharding (`jax.sharding`, `jax.shard_map`, `jax.distributed`).

Two ways to use several devices, each a thin layer over JAX (no scheduler of ddgjax's own):

- **A batch of shapes of one connectivity** (`batch_sharding`, `shard_batch`): put the `(B, nv, 3)`
  positions on the devices split along the batch and `jax.jit(jax.vmap(f))` them; XLA partitions
  the whole program along the batch. Energies, gradients, operators, and the solves by conjugate
  gradient (`linear_solve(..., solver="cg")`, the problems of `ddgjax.pde` with `solver="cg"`)
  shard; the host solvers (`"cholesky"`, `"superlu"`, `"pyamg"`) do not (`ddgjax.sharding._batch`).
- **One mesh too large for one device** (`partition_vertices`, `sharded_laplacian_apply`,
  `sharded_cg`): the vertices, reordered for locality, split in contiguous blocks, one per device,
  each device computing its own rows of `L u` after an explicit halo exchange (`jax.shard_map`);
  the conjugate gradient keeps every vector sharded (`ddgjax.sharding._partition`, `_operator`).
  Its preconditioner is Jacobi or algebraic multigrid (`sharded_cg(..., preconditioner="amg")`,
  `partition_amg`, `sharded_amg_hierarchy`, `ShardedAMG`): the finest level sharded like the vectors
  (its smoother the sharded product, $P_0^\top r$ summed across devices), the coarse levels' V-cycle
  replicated on every device (`ddgjax.sharding._amg`).

Several hosts: call `jax.distributed.initialize()` on every process before anything else;
`jax.devices()` (the default of `n_devices` / `devices` here) then spans all hosts.
"""

from ._amg import ShardedAMG as ShardedAMG
from ._amg import partition_amg as partition_amg
from ._batch import BATCH as BATCH
from ._batch import batch_sharding as batch_sharding
from ._batch import replicated as replicated
from ._batch import shard_batch as shard_batch
from ._devices import device_mesh as device_mesh
from ._operator import sharded_amg_hierarchy as sharded_amg_hierarchy
from ._operator import sharded_cg as sharded_cg
from ._operator import sharded_laplacian_apply as sharded_laplacian_apply
from ._partition import VERTICES as VERTICES
from ._partition import LocalPlan as LocalPlan
from ._partition import VertexPartition as VertexPartition
from ._partition import locality_order as locality_order
from ._partition import partition_vertices as partition_vertices
