"""Per-face distortion of a map of a triangle mesh into the plane: area, angles (quasi-conformality), flips.

A piecewise-linear map `uv` is affine on each face; its Jacobian `J` (`2 x 2`, from an orthonormal
frame of the face's plane to the plane of the map) has singular values `s_1 >= s_2 >= 0`. Write
`J = [[j11, j12], [j21, j22]]` as the sum of a similarity and an anti-similarity part,
`a = ((j11 + j22) / 2, (j21 - j12) / 2)` and `b = ((j11 - j22) / 2, (j21 + j12) / 2)`; then

    s_1 = |a| + |b|,   s_2 = | |a| - |b| |,   det J = |a|^2 - |b|^2,

so every measure below comes from two plane-vector norms (no eigenvalue problem, no square root of a
difference that cancels), and its gradient stays finite at conformal faces (`b = 0`).

- `conformal_distortion = s_1 / s_2 >= 1` (the quasi-conformal ratio, 1 exactly on faces mapped by a
  similarity); `+inf` on a face whose image collapses (`s_2 = 0`), with a zero gradient there.
- `conformal_energy = A (s_1 - s_2)^2 / 2 = 2 A |b|^2` on orientation-preserving faces, in general
  `A (|J|_F^2 / 2 - det J)`: the per-face conformal energy `E_D - A` that LSCM minimises (their sum is
  `1/2 x^T Q x`, `conformal_energy_matrix`). Smooth everywhere: the energy to optimise.
- `area_ratio = (A_uv / sum A_uv) / (A / sum A)`, signed (negative on flipped faces), 1 for a map
  that scales every face alike: normalised by the total areas, so a global scale does not count.
- `flipped`: signed uv area `<= 0` (orientation relative to the face's vertex order).

A face of zero surface area has no Jacobian: it gets `conformal_distortion = 1`, `area_ratio = 0`,
`conformal_energy = 0`, with finite (zero) gradients (`ddgjax._numerics` safe helpers).

References: K. Hormann, B. Levy, A. Sheffer, "Mesh parameterization: theory and practice" (SIGGRAPH
course, 2007), section 3 (singular values and distortion measures); the conformal / anti-conformal
split of a 2x2 matrix is the Wirtinger decomposition `f_z`, `f_zbar` (Beltrami coefficient
`|b| / |a|`). libigl: none per face (its `flipped_triangles` gives the flips); gpytoolbox: none.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_float_shape, is_traced
from .._indexing import take_rows
from .._numerics import cross2, safe_div, safe_norm
from ..mesh import Mesh, require_mesh


class MapDistortion(eqx.Module):
    """Per-face distortion of a map (module docstring for the formulas), with area-weighted summaries.

    Attributes:
        area_ratio: `(nf,)` normalised signed area ratio, 1 = the face keeps its share of the area.
        conformal_distortion: `(nf,)` `s_1 / s_2 >= 1` (`+inf` where the image collapses).
        conformal_energy: `(nf,)` `A (|J|_F^2 / 2 - det J) >= 0`, the face's share of `E_C = E_D - A`.
        flipped: `(nf,)` bool, signed uv area `<= 0`.
        surface_areas: `(nf,)` face areas on the surface (the weights of the summaries).
    """

    area_ratio: Float[Array, " nf"]
    conformal_distortion: Float[Array, " nf"]
    conformal_energy: Float[Array, " nf"]
    flipped: Bool[Array, " nf"]
    surface_areas: Float[Array, " nf"]

    @property
    def n_flipped(self) -> Int[Array, ""]:
        """Number of flipped faces."""
        return jnp.sum(self.flipped)

    @property
    def max_conformal_distortion(self) -> Float[Array, ""]:
        """Largest quasi-conformal ratio over the faces."""
        return jnp.max(self.conformal_distortion)

    @property
    def mean_conformal_distortion(self) -> Float[Array, ""]:
        """Area-weighted mean quasi-conformal ratio (1 for a conformal map)."""
        return safe_div(jnp.sum(self.surface_areas * self.conformal_distortion), jnp.sum(self.surface_areas))

    @property
    def total_conformal_energy(self) -> Float[Array, ""]:
        """`E_C = E_D - A` of the whole map (0 for a map that is a similarity on every face)."""
        return jnp.sum(self.conformal_energy)

    @property
    def mean_area_distortion(self) -> Float[Array, ""]:
        """Area-weighted mean of `|log area_ratio|` over unflipped faces of positive area (0: area-preserving up to scale)."""
        usable = (self.area_ratio > 0) & ~self.flipped
        logs = jnp.abs(jnp.log(jnp.where(usable, self.area_ratio, 1.0)))
        weights = jnp.where(usable, self.surface_areas, 0.0)
        return safe_div(jnp.sum(weights * logs), jnp.sum(weights))


def map_distortion(mesh: Mesh, uv: Float[ArrayLike, "nv 2"]) -> MapDistortion:
    """Per-face distortion of the map `uv` of `mesh` into the plane (module docstring), a `MapDistortion`.

    Works for any triangle mesh and any map (not only disks). Differentiable in the vertex positions
    and in `uv`, under `jit`, `grad` and `vmap`; finite values and gradients on zero-area faces.

    Args:
        mesh: any triangle mesh.
        uv: `(nv, 2)` positions in the plane.

    Returns:
        `MapDistortion` with `(nf,)` fields and summaries (`n_flipped`, `max_conformal_distortion`,
        `mean_conformal_distortion`, `total_conformal_energy`, `mean_area_distortion`).
    """
    mesh = require_mesh("mesh", mesh)
    expected = (mesh.n_vertices, 2)
    if np.shape(uv) != expected:
        raise DDGInputError(f"uv: expected shape {expected} (one plane position per vertex), got {np.shape(uv)}")
    check_float_shape("uv", uv if is_traced(uv) else np.asarray(uv), (2,))
    uv = device_array(uv)
    return _distortion(mesh.vertices, mesh.faces, uv if jnp.issubdtype(uv.dtype, jnp.floating) else uv.astype(float))


@kernel
def _distortion(vertices, faces, uv) -> MapDistortion:
    corners = take_rows(vertices, faces)
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    mapped = take_rows(uv, faces)
    f1, f2 = mapped[:, 1] - mapped[:, 0], mapped[:, 2] - mapped[:, 0]
    # Frame of the face: e1 / |e1| and its in-plane normal; there e1 = (l1, 0) and e2 = (c, h) with
    # c = e1.e2 / l1 and h = 2A / l1, so J = [f1 f2] [[l1, c], [0, h]]^{-1}.
    l1 = safe_norm(e1)
    double_area = safe_norm(jnp.cross(e1, e2))
    dot = jnp.sum(e1 * e2, axis=-1)
    column1 = safe_div(f1, l1[:, None])
    column2 = safe_div(f2 * (l1 * l1)[:, None] - f1 * dot[:, None], (l1 * double_area)[:, None])
    j11, j21, j12, j22 = column1[:, 0], column1[:, 1], column2[:, 0], column2[:, 1]
    a = safe_norm(jnp.stack([j11 + j22, j21 - j12], axis=-1)) / 2
    b = safe_norm(jnp.stack([j11 - j22, j21 + j12], axis=-1)) / 2
    areas = double_area / 2
    positive = areas > 0
    distortion = jnp.where(positive, safe_div(a + b, jnp.abs(a - b), jnp.inf), 1.0)
    # |J|_F^2 / 2 - det J = (|a|^2 + |b|^2) - (|a|^2 - |b|^2) = 2 |b|^2.
    energy = 2.0 * areas * b * b
    image_areas = cross2(f1, f2) / 2
    ratio = safe_div(image_areas * jnp.sum(areas), areas * jnp.sum(image_areas))
    return MapDistortion(
        area_ratio=jnp.where(positive, ratio, 0.0),
        conformal_distortion=distortion,
        conformal_energy=energy,
        flipped=image_areas <= 0,
        surface_areas=areas,
    )
