"""Pieces one ddgjax package needs from another that users should not call (as `lineax.internal`).

A package imports another package's public API, or a name from here; never a private module of
another package (DESIGN.md, layout). Names resolve on first use (PEP 562), so importing this module
loads nothing, and a low package can use it without importing the packages above it.
"""

from __future__ import annotations

import importlib

_NAMES = {
    # storage plans of vertex-vertex operators (ddgjax.laplacian; the type is ddgjax.laplacian.TriangulationPlan)
    "vertex_plan": "ddgjax.laplacian._plan",
    "dec_plan": "ddgjax.laplacian._plan",
    "edge_slot_maps": "ddgjax.laplacian._plan",
    "apply_slot_weights": "ddgjax.laplacian._cotan",
    "resolve_robust": "ddgjax.laplacian._operators",
    # the tufted cover of any triangles, flipped to intrinsic Delaunay on the host, and the JAX replay of flips (ddgjax.laplacian)
    "tufted_delaunay": "ddgjax.laplacian._tufted",
    "replayed_lengths_sq": "ddgjax.laplacian._intrinsic",
    # vertex positions checked and as a float array, simplex lists checked, and the surface topology builder (ddgjax.mesh; ddgjax.volume's boundary surface)
    "as_float_vertices": "ddgjax.mesh._mesh",
    "checked_vertices": "ddgjax.mesh._mesh",
    "build_topology": "ddgjax.mesh._topology",
    "validate_simplices": "ddgjax.mesh._topology",
    # the problem layer's checks of a TetMesh: robust=False only, no degenerate tets (ddgjax.volume)
    "require_tet_problem": "ddgjax.volume._check",
    # degenerate geometry: faces of (near-)zero area, found once per Mesh object (ddgjax.mesh)
    "degenerate_faces": "ddgjax.mesh._check",
    "require_nondegenerate": "ddgjax.mesh._check",
    # per-face edge coordinates, squared lengths and areas from gathered corner positions (ddgjax.mesh)
    "face_geometry_from_corners": "ddgjax.mesh._geometry",
    # the Dirichlet energy's derivatives in each face's squared edge lengths (ddgjax.laplacian)
    "dirichlet_energy_length_weights": "ddgjax.laplacian._cotan",
    # Dirichlet bookkeeping of a Poisson problem: fixed and pinned vertices, components (ddgjax.pde)
    "DirichletData": "ddgjax.pde._poisson",
    # linear algebra (ddgjax.solve)
    "PRECONDITIONERS": "ddgjax.solve._linear",
    "auto_method": "ddgjax.solve._linear",
    "preconditioned_cg": "ddgjax.solve._linear",
    "linear_solution": "ddgjax.solve._linear",
    # sparse patterns (ddgjax.sparse); DEC's signed incidence matrices (ddgjax.dec, ddgjax.volume)
    "incidence_matrix": "ddgjax.sparse._matrix",
    "stable_order": "ddgjax.sparse._pattern",
}


def __getattr__(name: str):
    if name not in _NAMES:
        raise AttributeError(f"module 'ddgjax.internal' has no attribute {name!r}")
    value = getattr(importlib.import_module(_NAMES[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(_NAMES)
