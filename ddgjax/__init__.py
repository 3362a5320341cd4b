"""ddgjax: discrete differential geometry in JAX, differentiable end to end.

Subpackages (each loaded on first use): `ddgjax.curves` (plane curves, four discrete curvatures,
curve-shortening flows), `ddgjax.mesh` (triangle meshes, geometry, curvature, built-in shapes),
`ddgjax.dec` (discrete exterior calculus), `ddgjax.laplacian` (cotan Laplacian, mass matrices,
intrinsic Delaunay), `ddgjax.discretization` (a triangle or tet mesh as the problems solve on it), `ddgjax.sparse` (fixed-pattern sparse matrices), `ddgjax.solve` (sparse linear
algebra: differentiable solves, CG, AMG), `ddgjax.pde` (Poisson / harmonic problems, Hodge
decomposition, mean curvature flow, energies), `ddgjax.spectral` (Laplacian eigenpairs),
`ddgjax.geodesics` (heat-method distance), `ddgjax.param` (surface parametrisation), `ddgjax.fields`
(direction fields), `ddgjax.optim` (shape optimisation), `ddgjax.deform` (k-harmonic and ARAP
deformation from handles), `ddgjax.matching` (shape correspondence by functional maps), `ddgjax.fluids`
(incompressible flow on surfaces), `ddgjax.pointcloud` (Laplacians and geodesics of point clouds), `ddgjax.reconstruct` (surfaces from points: Poisson reconstruction), `ddgjax.graph`
(graph Laplacians), `ddgjax.batch` (padded batches of meshes of different sizes), `ddgjax.learn` (operators for
learning on meshes, a DiffusionNet), `ddgjax.volume` (tetrahedral meshes: their
Laplacian, mass matrices and DEC), `ddgjax.sharding` (several devices), `ddgjax.io` (mesh files), `ddgjax.plot` (figures). The vocabulary every package shares (option names,
their values, outcomes) is the table in docs/conventions.md.

Failures that depend on values inside `jit` (a flow that self-intersects, a solve that does not
converge) are reported through one results convention, as lineax and optimistix do: `throw=True` by
default raises with the message of an item of `ddgjax.RESULTS`; `throw=False` returns a
`ddgjax.Solution` (`value`, `result`, `stats`), or the run's record: every record is a `ddgjax.Record`
with the same three names.

Importing ddgjax never changes `jax.config`; enable float64 yourself
(`jax.config.update("jax_enable_x64", True)`) for geometry work. ddgjax's own kernels compile with
`cpu_compiler_options()` on CPU; pass the same to a `jax.jit` of your own
(`jax.jit(f, compiler_options=ddgjax.cpu_compiler_options())`) to get their speed inside it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from ._errors import DDGInputError as DDGInputError
from ._errors import MeshDataError as MeshDataError

# Subpackages and names load on first use (PEP 562, as SciPy does): `import ddgjax` costs little more
# than importing JAX, and `ddgjax.pde` pulls in only what Poisson problems need.
_SUBPACKAGES = (
    "batch",
    "curves",
    "dec",
    "deform",
    "discretization",
    "fields",
    "fluids",
    "geodesics",
    "graph",
    "io",
    "laplacian",
    "learn",
    "matching",
    "mesh",
    "optim",
    "param",
    "pde",
    "plot",
    "pointcloud",
    "reconstruct",
    "sharding",
    "solve",
    "sparse",
    "spectral",
    "volume",
)
_NAMES = {
    "Curve": "curves",
    "Mesh": "mesh",
    "RESULTS": "_results",
    "Record": "_results",
    "Solution": "_results",
    "cpu_compiler_options": "_compile",
    "MASS_MATRICES": "_options",
    "LUMPED_MASS_MATRICES": "_options",
    "DUAL_CELLS": "_options",
    "LAPLACIAN_WEIGHTS": "_options",
    "BOUNDARY_CONDITIONS": "_options",
    "LINEAR_SOLVERS": "_options",
}

if TYPE_CHECKING:  # what static analysers and IDEs see; at run time __getattr__ below does the same lazily
    from . import batch as batch
    from . import curves as curves
    from . import dec as dec
    from . import deform as deform
    from . import discretization as discretization
    from . import fields as fields
    from . import fluids as fluids
    from . import geodesics as geodesics
    from . import graph as graph
    from . import io as io
    from . import laplacian as laplacian
    from . import learn as learn
    from . import matching as matching
    from . import mesh as mesh
    from . import optim as optim
    from . import param as param
    from . import pde as pde
    from . import plot as plot
    from . import pointcloud as pointcloud
    from . import reconstruct as reconstruct
    from . import sharding as sharding
    from . import solve as solve
    from . import sparse as sparse
    from . import spectral as spectral
    from . import volume as volume
    from ._compile import cpu_compiler_options as cpu_compiler_options
    from ._options import BOUNDARY_CONDITIONS as BOUNDARY_CONDITIONS
    from ._options import DUAL_CELLS as DUAL_CELLS
    from ._options import LAPLACIAN_WEIGHTS as LAPLACIAN_WEIGHTS
    from ._options import LINEAR_SOLVERS as LINEAR_SOLVERS
    from ._options import LUMPED_MASS_MATRICES as LUMPED_MASS_MATRICES
    from ._options import MASS_MATRICES as MASS_MATRICES
    from ._results import RESULTS as RESULTS
    from ._results import Record as Record
    from ._results import Solution as Solution
    from .curves import Curve as Curve
    from .mesh import Mesh as Mesh

__all__ = ["DDGInputError", "MeshDataError", "__version__", *_SUBPACKAGES, *_NAMES]


def __getattr__(name: str):
    if name in _SUBPACKAGES:
        module = importlib.import_module(f".{name}", __name__)
    elif name in _NAMES:
        module = getattr(importlib.import_module(f".{_NAMES[name]}", __name__), name)
    elif name == "__version__":
        from importlib.metadata import PackageNotFoundError, version

        try:
            module = version("ddgjax")
        except PackageNotFoundError:  # running from a source tree that is not installed
            module = "0.1.0"
    else:
        raise AttributeError(f"module 'ddgjax' has no attribute {name!r}")
    globals()[name] = module
    return module


def __dir__() -> list[str]:
    return sorted(__all__)
