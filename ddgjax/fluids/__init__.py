r"""Incompressible fluids on closed surfaces: vorticity - stream function Euler flow, differentiable end to end.

- `fluid_basis(mesh, k, *, mass="voronoi", robust=False) -> FluidBasis`: the first `k` Laplacian
  eigenpairs and the alternating advection tensor `W (k, k, k)` between them (Azencot et al. 2014),
  and on a surface of genus `g` its `2 g` harmonic velocity fields with their coupling tensors;
  built once per mesh, differentiable in the vertex positions.
- `euler_flow(mesh, vorticity, *, tau, steps, save_every=None, rotation=0.0, viscosity=0.0, dye=None,
  harmonic=None, k=64, basis=None, method="spectral", max_steps=32, rtol=None, progress=False,
  throw=True) -> EulerFlowResult`: the vorticity equation (optionally on a frame turning at `rotation`
  about +z, viscous, with a passive dye and a harmonic flow round the handles) reduced to the basis and
  integrated by implicit midpoint steps solved to round-off, which conserve energy and enstrophy; one
  compiled, checkpointed `lax.scan` differentiated implicitly per step; outcomes as `ddgjax.RESULTS`
  (`max_steps_reached` where a step's Newton iteration does not converge: `tau` too large; `nonfinite`).
- `stream_function_velocity(mesh, psi, *, at="faces")`: velocities $u = n \times \nabla\psi$, per face `(nf, 3)` or
  averaged at the vertices `(nv, 3)`.

$$\frac{\partial\omega}{\partial t} + u \cdot \nabla(\omega + 2\Omega z) = \nu \Delta\omega, \qquad u = n \times \nabla\psi, \qquad \Delta\psi = \omega$$

Reference: O. Azencot, S. Weissmann, M. Ovsjanikov, M. Wardetzky, M. Ben-Chen, "Functional fluids on
surfaces" (SGP 2014).
"""

from ._basis import FluidBasis as FluidBasis
from ._basis import fluid_basis as fluid_basis
from ._euler import EulerFlowResult as EulerFlowResult
from ._euler import euler_flow as euler_flow
from ._velocity import stream_function_velocity as stream_function_velocity
