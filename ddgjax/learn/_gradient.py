"""The spatial gradient at vertices in tangent frames, as a fixed-degree (ELL) table of weights.

For every vertex `i` with one-ring neighbours `j`, the edge vectors `x_j - x_i` are projected into
the vertex's tangent frame `(e1, e2)`, giving the rows `E_ij` (2-vectors). The tangent gradient
`g_i` of a vertex function `u` is the least-squares fit `min_g sum_j (E_ij . g - (u_j - u_i))^2`,
`g_i = (E_i^T E_i + eps I)^{-1} E_i^T du_i`, so `g_i = sum_j w_ij (u_j - u_i)` with the weights
`w_ij = (E_i^T E_i + eps I)^{-1} E_ij` (DiffusionNet's `build_grad`, Sharp et al. 2022, section 3.2).
The fit is exact for functions linear on a flat one-ring. `eps` is a ridge relative to
`trace(E_i^T E_i)`, so a one-ring that spans less than a plane (collinear or coincident neighbours)
gets finite weights.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._compile import kernel
from .._indexing import take_rows
from .._numerics import safe_div, safe_normalize
from ..fields import TangentBases
from ..mesh import Mesh, MeshTopology, vertex_normals

#: The ridge of the least-squares fit, relative to the one-ring's second moment: small enough to keep
#: the fit exact for linear functions to round-off, large enough for degenerate one-rings.
_RIDGE = 1e-12


def neighbor_table(topology: MeshTopology) -> Int[np.ndarray, "nv d"]:
    """`(nv, d)` the one-ring of every vertex (its edge neighbours), `d` the largest degree; free slots hold the vertex itself."""
    nv = topology.n_vertices
    edges = np.asarray(topology.edges).astype(np.int64)
    source = np.concatenate([edges[:, 0], edges[:, 1]])
    target = np.concatenate([edges[:, 1], edges[:, 0]])
    order = np.lexsort((target, source))
    source, target = source[order], target[order]
    degree = np.bincount(source, minlength=nv)
    start = np.concatenate([[0], np.cumsum(degree)[:-1]])
    slot = np.arange(source.size) - start[source]
    width = max(int(degree.max(initial=0)), 1)
    table = np.repeat(np.arange(nv, dtype=np.int64)[:, None], width, axis=1)
    table[source, slot] = target
    return table


@kernel
def gradient_frames_and_weights(mesh: Mesh, neighbors: Int[Array, "nv d"]) -> tuple[TangentBases, Float[Array, "nv d 2"]]:
    """The vertex frames and the `(nv, d, 2)` least-squares gradient weights of `neighbors` (module docstring).

    The frame: `normal` the angle-weighted vertex normal, `e1` the edge to the vertex's first
    neighbour projected into the tangent plane and normalised, `e2 = normal x e1`.
    """
    x = mesh.vertices
    normals = vertex_normals(mesh, weighting="angle")
    edges = take_rows(x, neighbors) - x[:, None, :]  # [i, j, xyz]
    first = edges[:, 0, :]
    e1 = safe_normalize(first - jnp.sum(first * normals, axis=-1, keepdims=True) * normals)
    e2 = jnp.cross(normals, e1)
    local = jnp.stack([jnp.einsum("ijc,ic->ij", edges, e1), jnp.einsum("ijc,ic->ij", edges, e2)], axis=-1)  # E_ij
    valid = neighbors != jnp.arange(x.shape[0])[:, None]
    local = jnp.where(valid[..., None], local, 0.0)
    gram = jnp.einsum("ija,ijb->iab", local, local)
    ridge = _RIDGE * (gram[:, 0, 0] + gram[:, 1, 1])
    a, b, c = gram[:, 0, 0] + ridge, gram[:, 0, 1], gram[:, 1, 1] + ridge
    det = a * c - b * b
    inverse = jnp.stack([jnp.stack([c, -b], -1), jnp.stack([-b, a], -1)], -2)
    inverse = safe_div(inverse, det[:, None, None])
    weights = jnp.einsum("iab,ijb->ija", inverse, local)
    return TangentBases(e1, e2, normals), weights
