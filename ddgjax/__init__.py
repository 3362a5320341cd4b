"""ddgjax: discrete differential geometry in JAX, differentiable end to end.

Subpackages: `ddgjax.curves` (plane curves, four discrete curvatures, curve-shortening flows),
`ddgjax.mesh` (triangle meshes, geometry, curvature, built-in shapes), `ddgjax.dec` (discrete exterior
calculus), `ddgjax.laplacian` (cotan Laplacian, mass matrices), `ddgjax.sparse` (fixed-pattern sparse
matrices), `ddgjax.solve` (energies and differentiable sparse solves), `ddgjax.spectral` (Laplacian
eigenpairs), `ddgjax.geodesics` (heat-method distance), `ddgjax.param` (surface parametrisation), `ddgjax.fields` (direction fields),
`ddgjax.io` (mesh files),
`ddgjax.plot` (figures). Conventions: see DESIGN.md and the README.

Failures that depend on values inside `jit` (a flow that self-intersects, later a solve that does not
converge) are reported through one results convention, as lineax and optimistix do: a `result`
field holding an item of `ddgjax.RESULTS`, and `throw=True` by default.

Importing ddgjax never changes `jax.config`; enable float64 yourself
(`jax.config.update("jax_enable_x64", True)`) for geometry work. ddgjax's own kernels compile with
`cpu_compiler_options()` on CPU; pass the same to a `jax.jit` of your own
(`jax.jit(f, compiler_options=ddgjax.cpu_compiler_options())`) to get their speed inside it.
"""

from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version

from . import curves as curves
from . import dec as dec
from . import fields as fields
from . import geodesics as geodesics
from . import io as io
from . import laplacian as laplacian
from . import mesh as mesh
from . import optim as optim
from . import param as param
from . import solve as solve
from . import sparse as sparse
from . import spectral as spectral
from ._compile import cpu_compiler_options as cpu_compiler_options
from ._errors import DDGInputError as DDGInputError
from ._errors import MeshDataError as MeshDataError
from ._results import RESULTS as RESULTS
from .curves import Curve as Curve
from .mesh import Mesh as Mesh

try:
    __version__ = _version("ddgjax")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.1.0"
