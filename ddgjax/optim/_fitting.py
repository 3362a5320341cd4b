"""The mesh-fitting objective of PyTorch3D's "deform a source mesh to fit a target" tutorial, as one function.

`mesh_fitting_loss(target, n_samples=...)` returns `loss(mesh, key)`:

    chamfer(sample_points(mesh, n_samples, key=key), target)
        + edge_weight * edge_length_loss(mesh)
        + normal_weight * normal_consistency_loss(mesh)
        + laplacian_weight * laplacian_smoothing_loss(mesh)

with fresh surface samples every call (the key), the tutorial's default weights (1, 0.01, 0.1), for
`minimize_shape(loss, source, steps=..., key=...)`. Reference: PyTorch3D tutorial
"Deform a source mesh to form a target mesh using 3D loss functions" (its `w_chamfer`, `w_edge`,
`w_normal`, `w_laplacian`).
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._errors import check_count
from ..mesh import Mesh
from ._chamfer import _check_points, chamfer_distance, sample_points
from ._objectives import edge_length_loss, laplacian_smoothing_loss, normal_consistency_loss


def mesh_fitting_loss(
    target: Float[ArrayLike, "n 3"],
    *,
    n_samples: int = 5_000,
    edge_weight: float = 1.0,
    normal_weight: float = 0.01,
    laplacian_weight: float = 0.1,
) -> Callable[[Mesh, PRNGKeyArray], Float[Array, ""]]:
    """`loss(mesh, key)`: Chamfer distance of `n_samples` fresh surface samples to `target` plus PyTorch3D's
    regularisers (module docstring), a scalar `()` differentiable in the vertex positions.

    Args:
        target: `(n, 3)` target points (e.g. `sample_points(target_mesh, n, key=key)`).
        n_samples: surface samples of the mesh per call (default 5000).
        edge_weight, normal_weight, laplacian_weight: the regularisers' weights (the tutorial's 1, 0.01, 0.1).

    Returns:
        The function `loss(mesh, key)` of a `Mesh` and a JAX PRNG key, returning a scalar float array `()`.
    """
    _check_points("target", target)
    target = jnp.asarray(target)
    n_samples = check_count("n_samples", n_samples)

    def loss(mesh: Mesh, key: PRNGKeyArray) -> Float[Array, ""]:
        return (
            chamfer_distance(sample_points(mesh, n_samples, key=key), target)
            + edge_weight * edge_length_loss(mesh)
            + normal_weight * normal_consistency_loss(mesh)
            + laplacian_weight * laplacian_smoothing_loss(mesh)
        )

    return loss
