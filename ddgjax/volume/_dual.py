"""Dual cells of a tetrahedral mesh: the volume of each vertex's dual cell (`*0`), for the mass matrices and DEC."""

from __future__ import annotations

from jaxtyping import Array, Float

from .._errors import check_choice
from ._laplacian import barycentric_volumes, tet_plan
from ._tet_mesh import TetMesh

#: The duals of a tet mesh (`dual=`): the names and meanings of the surface duals (`ddgjax.dec`).
TET_DUALS = ("voronoi", "circumcentric", "barycentric")


def vertex_dual_volumes(tet_mesh: TetMesh, *, dual: str = "voronoi") -> Float[Array, " nv"]:
    """`(nv,)` the volume of each vertex's dual cell; they sum to the solid's volume."""
    check_choice("dual", dual, TET_DUALS)
    return barycentric_volumes(tet_mesh, tet_plan(tet_mesh))
