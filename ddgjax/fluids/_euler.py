"""Incompressible Euler flow on a closed surface, in the Laplacian eigenbasis, as one compiled `lax.scan`.

The vorticity equation with an optional rotating frame, viscosity and a passive dye,

    dw/dt + u . grad(w + f) = nu Delta w,     dc/dt + u . grad c = 0,     u = n x grad psi + h,  Delta psi = w,

(`f = 2 Omega z` the Coriolis parameter of a frame turning at `Omega` about +z) is projected on the
first `k` eigenfunctions (`FluidBasis`; Azencot et al. 2014): with `w = Phi a`, `psi = Phi b`,
`b_i = -a_i / lambda_i`, `f = Phi f`, `c = Phi g`,

    da_k/dt = sum_ij W_kij b_i (a_j + f_j) - nu lambda_k a_k,     dg_k/dt = sum_ij W_kij b_i g_j.

On a surface of genus `g` the velocity also has a harmonic part `h = sum_m c_m h_m` (`2 g` fields,
`FluidBasis`): it advects like the rest (`sum_m c_m H_kmj` joins `sum_i W_kij b_i`), and it evolves by
the harmonic projection of the momentum equation `du/dt = -(w + f) n x u - grad(p + |u|^2 / 2)`:

    dc_m/dt = sum_kj H_kmj b_k (a_j + f_j) - sum_kn (a_k + f_k) G_kmn c_n,

the exchange that keeps the total kinetic energy `1/2 sum lambda b^2 + 1/2 sum c^2` (Kelvin's
theorem for the loops round the handles).

Integrator: the implicit midpoint rule on the state `x = (a, c)`, `x' = x + tau F((x + x') / 2)`,
viscosity included (for the linear viscous term it is Crank-Nicolson). The midpoint `x = (a + a') / 2`
solves `R(x) = D x - a - tau/2 N(x) = 0` (`D = 1 + tau nu lambda / 2`, `N` the quadratic advection),
to round-off (`euler_flow`'s `rtol`, default `CONVERGENCE` = 16 ulps): first fixed-point iterations
`x <- D^{-1} (a + tau/2 N(x))` from `x = a`, one `k^3` product each, while each moves `x` at most
`CONTRACTION` times the last move (5-7 of them at the usual `tau`, where `tau |N'|` is small), until
one moves `x` by at most `rtol max|a|`; then, where they stopped contracting, Newton steps (`k x k`
Newton matrix `J = D - tau/2 N'`) from the last iterate, or from the iterate of least residual (`a`
itself at a large `tau`) where the iterates ran away, until a step moves `x` by at most
`rtol max|a| |J|_inf` (the residual's round-off grows with `J`; measured, the steps' floor stays
at most 1.1 `|J|_inf` ulps of `max|a|` up to `tau |N'|` ~ 100), at most `max_steps` of them. Both are
`lax.while_loop`s; the gradient does not go through them (below). A step whose Newton iteration does
not converge (or diverges) is a failure, `RESULTS.max_steps_reached`, never an unsolved step passed on.

Step-size limit. `N' = dN/dx`, the advection's Jacobian in the coefficients, has the size of the
largest vorticity (measured on the unit sphere, `|N'(a)|_2` lies between 0.5 and 1.8 `max |w|`: the
inverse turnover time). The fixed-point map contracts where `tau/2 |N'| < 1` (`|D^{-1}| <= 1`), so it
alone solves steps with `tau |N'| < 2`. Newton converges quadratically from `x_0` when (Kantorovich)
`|J_0^{-1}|^2 tau/2 |N''| |R(x_0)| <= 1/2`, `N''` the constant bilinear advection tensor; from
`x_0 = a`, `R(a) = -tau/2 N(a)` (inviscid) and `|N''| |N(a)| ~ |N'(a)|^2`, so this guarantee holds for
`tau |N'(a)|` of order 1. Newton reaches much further in practice: on the unit sphere (12 random
vorticities of degrees 1 to 3 with unit normal coefficients, 20 steps at each `tau`; icosphere(2),
k = 16 and icosphere(3), k = 36 and 64) every step converged, in 5-7 Newton steps (up to ~30 near the
limit), while `tau |N'(a)|_2 <= 10`; the first failures came at `tau |N'(a)|_2` = 13 (k = 36), 21
(k = 64) and 80 (k = 16); at `tau` = 100 on icosphere(2), k = 16, 13 of 20 such runs fail (the rest
keep energy and enstrophy to 1e-14). Beyond the limit the midpoint equation still has a solution
(energy conservation makes `R` coercive: `<R(x), x>_E >= |x|_E^2 - |a|_E |x|_E` in the energy inner
product, so a root lies in `|x|_E <= |a|_E`), but not a unique one, and Newton from `a` wanders:
lower `tau` (raising `max_steps` rarely helps).

The rule conserves every quadratic invariant of the ODE, for any root of `R`; with the alternating
tensor these are the kinetic energy `1/2 sum lambda b^2` and the enstrophy of the absolute vorticity
`1/2 sum (a + f)^2` (the relative enstrophy `1/2 sum a^2` without rotation). Measured on the unit sphere
(icosphere(3), k = 36, 200 steps of a random vorticity of degrees 1 to 3 with unit normal
coefficients), the largest relative drift of energy and enstrophy is 2e-15 at `tau` = 0.01, 0.05, 0.2
and 0.5 (round-off; a fixed count of 1 or 2 Newton steps drifts 1e-7 to 1e-2 and 7e-16 to 1e-6, and
a fixed 3, as before, drifted 3e-4 at `tau` = 10 on icosphere(2), k = 16, unreported). The
dye's midpoint step is linear (a Cayley transform of the antisymmetric `sum_i W_kij b_i`): its `L^2`
norm is kept exactly.

Differentiable in reverse mode with respect to the initial vorticity, the harmonic coefficients, the
dye, `tau`, `rotation`, `viscosity` and (through `fluid_basis`) the vertex positions. The midpoint is
differentiated implicitly (`jax.custom_vjp`: one transposed solve with the converged Newton matrix, the
implicit function theorem, rather than reverse mode through the Newton steps), and each saved chunk
is checkpointed, so reverse-mode memory grows with the number of saved states, not of steps.

Reference: O. Azencot, S. Weissmann, M. Ovsjanikov, M. Wardetzky, M. Ben-Chen, "Functional fluids on
surfaces" (SGP 2014); B. Haurwitz, "The motion of atmospheric disturbances on the spherical earth"
(J. Marine Research, 1940) for the Rossby-Haurwitz waves of the tests.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, Real

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_choice, check_count, check_positive, is_traced
from .._loop import (
    Failure,
    check_progress,
    check_steps,
    check_time_step,
    failed_before,
    finite_outcome,
    first_failure_step,
    no_failure,
    record,
    run_chunks,
    scan_steps,
)
from .._results import RESULTS, Record, raise_if_failed
from ..mesh import Mesh, require_mesh
from ._basis import FluidBasis, check_basis_size, fluid_basis, inverse_values

#: At most this many fixed-point iterations per implicit midpoint step, then at most `max_steps`
#: Newton steps (module docstring).
FIXED_POINT_STEPS = 10
#: Fixed-point iterations go on while each moves the midpoint at most this fraction of the last move
#: (10 iterations then reach round-off; a slower contraction hands over to Newton).
CONTRACTION = 0.01
#: `euler_flow`'s default `rtol`, in ulps of the dtype: the midpoint is converged when an iteration moves
#: it by at most this many ulps of the state's size (a Newton step: times the Newton matrix's norm).
CONVERGENCE = 16


class EulerFlowResult(Record):
    """Saved states of `euler_flow`: the (projected) initial state and one every `save_every` steps.

    `s = steps // save_every + 1` states.

    Attributes:
        vorticity: `(s, nv)` the vorticity `w = Phi a` at the vertices; `value` is the last.
        stream_function: `(s, nv)` `psi = Phi b`, `Delta psi = w` (no constant part).
        dye: `(s, nv)` the dye `Phi g` at the vertices, or None when `euler_flow` had none.
        coefficients: `(s, k)` the vorticity's basis coefficients `a`.
        harmonic: `(s, h)` the harmonic velocity's coefficients `c` (`FluidBasis.harmonic_velocity`;
            `h = 2 g`, 0 on a sphere). The velocity of state `i` is
            `stream_function_velocity(mesh, stream_function[i]) + basis.harmonic_velocity(harmonic[i])`.
        kinetic_energy: `(s,)` `1/2 int |u|^2 = 1/2 sum lambda_i b_i^2 + 1/2 sum c_m^2`.
        enstrophy: `(s,)` `1/2 int w^2 = 1/2 sum a_i^2` (of the relative vorticity).
        times: `(s,)` flow times `step * tau`.
        steps: `(s,)` the step numbers of the saved states.
        fixed_point_steps: `(s,)` int, the most fixed-point iterations of one implicit midpoint step
            among the steps since the previous saved state (0 for the initial state).
        newton_steps: `(s,)` int, likewise the most Newton steps (at most `max_steps`; 0 where the
            fixed point converged alone, as at small `tau`).
        tau: the time step.
        result: the outcome of the first failing step (`ddgjax.RESULTS`): `successful`,
            `max_steps_reached` (the step's midpoint equation was not solved to `rtol` within
            `max_steps` Newton steps, or the iteration diverged: `tau` above the Newton limit of the
            module docstring; that step's state is the unconverged one, possibly not finite) or
            `nonfinite`. `euler_flow(..., throw=True)` (the default) raises instead of returning it.
        first_failure_step: int scalar, that step's number (`1, ..., steps`; 0 for non-finite traced
            input), `steps + 1` when none failed. Later saved states repeat the failed state.
    """

    vorticity: Float[Array, "s nv"]
    stream_function: Float[Array, "s nv"]
    dye: Float[Array, "s nv"] | None
    coefficients: Float[Array, "s k"]
    harmonic: Float[Array, "s h"]
    kinetic_energy: Float[Array, " s"]
    enstrophy: Float[Array, " s"]
    times: Float[Array, " s"]
    steps: Int[Array, " s"]
    fixed_point_steps: Int[Array, " s"]
    newton_steps: Int[Array, " s"]
    tau: Float[Array, ""]
    result: RESULTS
    first_failure_step: Int[Array, ""]

    @property
    def value(self) -> Float[Array, " nv"]:
        """The final vorticity at the vertices, `vorticity[-1]`."""
        return self.vorticity[-1]

    @property
    def stats(self) -> dict[str, Array]:
        """The run's history per saved state, as the fields hold it: `times`, `steps`, `kinetic_energy`,
        `enstrophy`, `fixed_point_steps`, `newton_steps`."""
        return {
            "times": self.times,
            "steps": self.steps,
            "kinetic_energy": self.kinetic_energy,
            "enstrophy": self.enstrophy,
            "fixed_point_steps": self.fixed_point_steps,
            "newton_steps": self.newton_steps,
        }


def euler_flow(
    mesh: Mesh,
    vorticity: Float[ArrayLike, " nv"],
    *,
    tau: Real[ArrayLike, ""],
    steps: int,
    save_every: int | None = None,
    rotation: Real[ArrayLike, ""] = 0.0,
    viscosity: Real[ArrayLike, ""] = 0.0,
    dye: Float[ArrayLike, " nv"] | None = None,
    harmonic: Float[ArrayLike, " h"] | None = None,
    k: int = 64,
    basis: FluidBasis | None = None,
    method: str = "spectral",
    max_steps: int = 32,
    rtol: float | None = None,
    progress: bool = False,
    throw: bool = True,
) -> EulerFlowResult:
    r"""Incompressible (Navier-Stokes) Euler flow of a vorticity on a closed surface (module docstring).

    $$\frac{\partial w}{\partial t} + u \cdot \nabla(w + 2\Omega z) = \nu \Delta w, \qquad u = n \times \nabla\psi, \qquad \Delta\psi = w,$$

    reduced to
    the first `k` Laplacian eigenfunctions (Azencot et al. 2014) and integrated by implicit midpoint
    steps (solved to round-off), which conserve energy and enstrophy of the inviscid,
    non-rotating flow to round-off. The step's nonlinear solve reaches up to `tau |N'| ~ 10`, `|N'|`
    the advection's rate, of the order of the largest vorticity `max |w|` (module docstring, step-size
    limit); a step beyond it that does not converge fails with `RESULTS.max_steps_reached`. One
    compiled `lax.scan` over saved chunks, differentiable:

        basis = fluid_basis(mesh, 36)
        jax.grad(lambda w0: loss(euler_flow(mesh, w0, tau=0.01, steps=100, basis=basis).value))(w0)

    Args:
        mesh: a closed, consistently oriented triangle mesh (unit sphere: `ddgjax.mesh.icosphere`).
        vorticity: `(nv,)` pointwise vorticity `n . curl u` at the vertices (outward normal); it is
            projected on the basis (`vorticity[0]` of the result is the projection).
        tau: time step, > 0 (may be traced).
        steps: number of steps, >= 1.
        save_every: save every this many steps; must divide `steps` (default `steps`).
        rotation: `Omega`, the frame's angular velocity about +z (Coriolis parameter `2 Omega z`, `z`
            the vertices' third coordinate). Default 0.
        viscosity: `nu >= 0`, the kinematic viscosity. Default 0 (inviscid).
        dye: `(nv,)` a passive scalar advected by the flow (projected on the basis), or None.
        harmonic: `(2 g,)` the initial harmonic velocity's coefficients on a surface of genus `g`
            (`FluidBasis.harmonic_coefficients` of a face velocity field gives them), default 0.
        k: number of eigenfunctions when `basis` is None (default 64 = 8^2: degrees up to 7 on a sphere).
        basis: a `FluidBasis` of this mesh (`fluid_basis`), kept for repeated runs; `k` is then its own.
        method: `"spectral"` (the only one).
        max_steps: the most Newton steps of one implicit midpoint step, after at most
            `FIXED_POINT_STEPS` = 10 fixed-point iterations (default 32; 5-7 are typical where Newton
            is needed, up to ~30 near its limit). A step that does not converge within them fails
            with `RESULTS.max_steps_reached`.
        rtol: the midpoint is solved when a fixed-point iteration moves it by at most `rtol * max|x_0|`,
            or a Newton step by at most `rtol * max|x_0| * |J|_inf` (`x_0` the state before the step,
            `J` the Newton matrix, whose size scales the residual's round-off). Default 16 ulps of the
            dtype (`CONVERGENCE`): round-off, so that energy and enstrophy are kept to round-off.
        progress: a tqdm progress bar over the saved chunks (concrete inputs only).
        throw: raise when a step fails (default): its midpoint equation unsolved (`max_steps_reached`) or
            a state not finite (`nonfinite`); or return the record to inspect `result`.

    Returns:
        `EulerFlowResult`: `vorticity`, `stream_function`, `dye` `(s, nv)`, `coefficients` `(s, k)`,
        `harmonic` `(s, 2 g)`, `kinetic_energy`, `enstrophy`, `times`, `steps`, `fixed_point_steps`,
        `newton_steps` `(s,)`, `value` (the final vorticity), `tau`, `result`, `first_failure_step`, `stats`.

    Raises:
        DDGInputError: `mesh` not a `Mesh`; `vorticity` or `dye` not of shape `(nv,)` or not finite;
            bad `tau`, `steps`, `save_every`, `rotation`, `viscosity` (< 0), `harmonic`, `k`, `basis`, `method`,
            `max_steps`, `rtol`, `progress` with traced input; a mesh `fluid_basis` refuses.
        equinox.EquinoxRuntimeError: with `throw=True`, a step whose midpoint equation was not solved
            (`RESULTS.max_steps_reached`: lower `tau`, module docstring) or a non-finite state
            (`RESULTS.nonfinite`).

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(2)
        >>> x, y, z = sphere.vertices.T
        >>> run = ddgjax.fluids.euler_flow(sphere, x * y + z, tau=0.05, steps=20, k=16)
        >>> run.vorticity.shape, bool(jnp.allclose(run.kinetic_energy, run.kinetic_energy[0]))  # energy is conserved
        ((2, 162), True)
    """
    mesh = require_mesh("mesh", mesh)
    check_choice("method", method, ("spectral",))
    check_choice("throw", throw, (False, True))
    steps, save_every = check_steps(steps, save_every)
    dtype = mesh.vertices.dtype
    vorticity = _vertex_function("vorticity", vorticity, mesh)
    dye = None if dye is None else _vertex_function("dye", dye, mesh)
    tau = check_time_step(tau, dtype)
    rotation = _scalar("rotation", rotation, dtype)
    viscosity = _scalar("viscosity", viscosity, dtype, nonnegative=True)
    # Device scalars, not static: one program serves every max_steps and rtol.
    max_steps = jax.device_put(np.asarray(check_count("max_steps", max_steps), np.int32))
    rtol = CONVERGENCE * np.finfo(dtype).eps if rtol is None else check_positive("rtol", rtol)
    rtol = jax.device_put(np.asarray(rtol, dtype))
    progress = check_progress(progress, vorticity, dye, harmonic, tau, rotation, viscosity, basis)
    if basis is None:
        basis = fluid_basis(mesh, check_basis_size(mesh, k))
    elif not isinstance(basis, FluidBasis):
        raise DDGInputError(f"basis: expected a FluidBasis (ddgjax.fluids.fluid_basis(mesh, k)), got {type(basis).__name__}")
    elif basis.vectors.shape[0] != mesh.n_vertices:
        raise DDGInputError(f"basis: made for {basis.vectors.shape[0]} vertices, this mesh has {mesh.n_vertices}")
    n_harmonic = basis.harmonic.shape[1]
    if harmonic is None:
        harmonic = device_array(np.zeros(n_harmonic, dtype))
    elif np.iscomplexobj(harmonic) or np.shape(harmonic) != (n_harmonic,):
        raise DDGInputError(
            f"harmonic: expected a real array of shape ({n_harmonic},) (2 x the genus: coefficients of basis.harmonic), "
            f"got shape {np.shape(harmonic)}"
        )
    elif not is_traced(harmonic) and not np.all(np.isfinite(np.asarray(harmonic))):
        raise DDGInputError(f"harmonic: expected finite values, got {np.asarray(harmonic)}")
    run = functools.partial(_states, progress=True) if progress else _run
    state = _initial_state(basis, vorticity, device_array(harmonic, dtype), dye)
    (coefficients, harmonic, dye_coefficients), counts, failure = run(
        basis, state, tau, rotation, viscosity, max_steps, rtol, steps=steps, save_every=save_every
    )
    flow = _flow_record(basis, coefficients, harmonic, dye_coefficients, counts, tau, failure, steps=steps, save_every=save_every)
    return raise_if_failed(flow, flow.result, throw)


# Eagerly, the set-up and the record are one program each (kept across processes), not ~25
# operations compiled one by one.
@kernel
def _initial_state(basis: FluidBasis, vorticity, harmonic, dye):
    """`(a, c, d)`: the basis coefficients of the vorticity and the dye, and the harmonic coefficients."""
    return basis.coefficients(vorticity), harmonic, None if dye is None else basis.coefficients(dye)


@kernel(static_argnames=("steps", "save_every"))
def _flow_record(
    basis: FluidBasis, coefficients, harmonic, dye_coefficients, counts, tau, failure, *, steps: int, save_every: int
):
    """The `EulerFlowResult` of the saved states' coefficients (module docstring: energy and enstrophy)."""
    saved = save_every * jnp.arange(steps // save_every + 1, dtype=jnp.int32)
    stream = basis.stream_coefficients(coefficients)
    return EulerFlowResult(
        vorticity=basis.function(coefficients),
        stream_function=basis.function(stream),
        dye=None if dye_coefficients is None else basis.function(dye_coefficients),
        coefficients=coefficients,
        harmonic=harmonic,
        kinetic_energy=0.5 * (jnp.sum(basis.values * stream**2, axis=-1) + jnp.sum(harmonic**2, axis=-1)),
        enstrophy=0.5 * jnp.sum(coefficients**2, axis=-1),
        times=tau * saved.astype(tau.dtype),
        steps=saved,
        fixed_point_steps=counts[:, 0],
        newton_steps=counts[:, 1],
        tau=tau,
        result=failure.result,
        first_failure_step=first_failure_step(failure, steps),
    )


def _vertex_function(name: str, values, mesh: Mesh) -> Float[Array, " nv"]:
    """`values` as a real `(nv,)` array of the mesh's dtype (finite, when concrete)."""
    if np.iscomplexobj(values) or np.shape(values) != (mesh.n_vertices,):
        raise DDGInputError(
            f"{name}: expected a real array of shape ({mesh.n_vertices},) (one value per vertex), got shape {np.shape(values)}"
        )
    if not is_traced(values) and not np.all(np.isfinite(np.asarray(values))):
        raise DDGInputError(
            f"{name}: expected finite values; entries {np.flatnonzero(~np.isfinite(np.asarray(values)))[:10]} are not"
        )
    return jnp.asarray(values).astype(mesh.vertices.dtype)


def _scalar(name: str, value, dtype, *, nonnegative: bool = False) -> Real[Array, ""]:
    """`value`, a finite real scalar (`>= 0` with `nonnegative`; checked when concrete), as an array of `dtype`."""
    expected = "a finite real number" + (" >= 0" if nonnegative else "")
    if np.ndim(value) != 0 or np.iscomplexobj(value) or isinstance(value, (bool, np.bool_)):
        raise DDGInputError(f"{name}: expected {expected}, got {value!r}")
    if not is_traced(value) and not (np.isfinite(value) and (value >= 0 or not nonnegative)):
        raise DDGInputError(f"{name}: expected {expected}, got {np.asarray(value).item()!r}")
    return jnp.asarray(value).astype(dtype) if is_traced(value) else jax.device_put(np.asarray(value, dtype))


class _Dynamics(eqx.Module):
    """The reduced equations' coefficients: the basis tensors, the damping and the absolute vorticity's offset."""

    advection: Float[Array, "k k k"]
    # W_kij and H_kmj with the summed index first, (i, k j) and (m, k j): the transport is then one
    # vector-matrix product (the layout is made once per chunk, not at every product).
    advection_by_stream: Float[Array, "k kk"]
    harmonic_advection_by_field: Float[Array, "h kk"]
    harmonic_advection: Float[Array, "k h k"]
    harmonic_exchange: Float[Array, "k h h"]
    inverse: Float[Array, " k"]
    damping: Float[Array, " n"]
    coriolis: Float[Array, " k"]
    half: Float[Array, ""]

    def transport(self, vorticity, harmonic) -> Float[Array, "k k"]:
        """`T_kj = sum_i W_kij b_i + sum_m H_kmj c_m`: `d q_k / dt = sum_j T_kj q_j` for an advected `q`."""
        stream = -vorticity * self.inverse
        k = stream.shape[0]
        return (stream @ self.advection_by_stream + harmonic @ self.harmonic_advection_by_field).reshape(k, k)

    def split(self, x):
        k = self.inverse.shape[0]
        return x[:k], x[k:]

    def residual(self, midpoint, start):
        """`D x - x_0 - tau/2 F(x)` of the stacked state `x = (a, c)` (module docstring)."""
        return self.damping * midpoint - start - self.half * self.rate(midpoint)

    def rate(self, x) -> Float[Array, " n"]:
        """`F(x)`: the advection part of `(da/dt, dc/dt)` (module docstring)."""
        vorticity, harmonic = self.split(x)
        absolute = vorticity + self.coriolis
        along = jnp.tensordot(self.harmonic_advection, absolute, axes=([2], [0]))  # sum_j H_kmj q_j: (k, h)
        exchange = jnp.tensordot(absolute, self.harmonic_exchange, axes=([0], [0]))  # sum_k q_k G_kmn: (h, h)
        stream = -vorticity * self.inverse
        return jnp.concatenate([self.transport(vorticity, harmonic) @ absolute, along.T @ stream - exchange @ harmonic])

    def system(self, x) -> Float[Array, "n n"]:
        """`dR/dx = D - tau/2 dF/dx`, the Newton matrix, block by block through `b = -a / lambda`, `q = a + f`, `c`."""
        vorticity, harmonic = self.split(x)
        absolute = vorticity + self.coriolis
        stream = -vorticity * self.inverse
        along = jnp.tensordot(self.harmonic_advection, absolute, axes=([2], [0]))
        by_vorticity = (
            self.transport(vorticity, harmonic) - jnp.tensordot(self.advection, absolute, axes=([2], [0])) * self.inverse
        )
        harmonic_by_vorticity = (
            -along.T * self.inverse
            + jnp.tensordot(stream, self.harmonic_advection, axes=([0], [0]))
            - jnp.tensordot(self.harmonic_exchange, harmonic, axes=([2], [0])).T
        )
        exchange = jnp.tensordot(absolute, self.harmonic_exchange, axes=([0], [0]))
        jacobian = jnp.block([[by_vorticity, along], [harmonic_by_vorticity, -exchange]])
        return jnp.diag(self.damping) - self.half * jacobian


@jax.custom_vjp
def _midpoint(dynamics: _Dynamics, start, max_steps, rtol, active):
    """The implicit midpoint `x = (x_0 + x_1) / 2`, `R(x) = 0` to `rtol` (module docstring).

    Returns `(x, counts, converged)`: `counts` the fixed-point iterations and Newton steps taken
    (int32 `(2,)`), `converged` whether the last iteration met the tolerance. With `active` false
    (a flow stopped by an earlier failure) nothing is iterated.
    """
    tolerance = rtol * jnp.max(jnp.abs(start))
    zero = jnp.zeros((), jnp.int32)

    def contracting(carry):
        count, _, _, _, change, fast = carry
        return active & (count < FIXED_POINT_STEPS) & (change > tolerance) & fast

    def fixed_point(carry):
        count, x, best, smallest, change, _ = carry
        new = (start + dynamics.half * dynamics.rate(x)) / dynamics.damping
        new_change = jnp.max(jnp.abs(new - x))
        # R(x) = D (x - new): each iteration measures the residual of the iterate it starts from.
        residual = jnp.max(jnp.abs(dynamics.damping * (x - new)))
        better = residual < smallest
        best, smallest = jnp.where(better, x, best), jnp.where(better, residual, smallest)
        return count + 1, new, best, smallest, new_change, new_change < CONTRACTION * change

    infinite = jnp.asarray(jnp.inf, start.dtype)
    fixed_steps, x, best, _, change, fast = jax.lax.while_loop(
        contracting, fixed_point, (zero, start, start, infinite, infinite, jnp.asarray(True))
    )
    # Newton goes on from the last iterate where the iteration converged or still contracted; from the
    # iterate of least residual (the state itself, at a large tau) where it did not: the iterates then run away.
    x = jnp.where(fast | (change <= tolerance), x, best)

    def unconverged(carry):
        count, x, converged = carry
        # A diverging iteration stops at its first non-finite iterate rather than at max_steps.
        return active & (count < max_steps) & ~converged & jnp.all(jnp.isfinite(x))

    def newton(carry):
        count, x, _ = carry
        system = dynamics.system(x)
        step = jnp.linalg.solve(system, dynamics.residual(x, start))
        # The residual's round-off grows with the Newton matrix (tau times the advection's size), and so
        # does the steps' floor: measured at most 1.1 |system|_inf ulps of max|x_0| (tau <= 100, k <= 64).
        converged = jnp.max(jnp.abs(step)) <= tolerance * jnp.max(jnp.sum(jnp.abs(system), axis=1))
        return count + 1, x - step, converged

    newton_steps, midpoint, converged = jax.lax.while_loop(unconverged, newton, (zero, x, change <= tolerance))
    return midpoint, jnp.stack([fixed_steps, newton_steps]), converged


def _midpoint_forward(dynamics, start, max_steps, rtol, active):
    solved = _midpoint(dynamics, start, max_steps, rtol, active)
    return solved, (dynamics, start, solved[0])


def _midpoint_backward(saved, cotangents):
    # The implicit function theorem on R(x, p) = 0: one transposed solve with the converged Newton
    # matrix, instead of reverse mode through the Newton iterations. The counts, the flag and the
    # iteration's limits carry no derivative.
    dynamics, start, midpoint = saved
    adjoint = jnp.linalg.solve(dynamics.system(midpoint).T, cotangents[0])
    _, pullback = jax.vjp(lambda dynamics, start: dynamics.residual(midpoint, start), dynamics, start)
    return (*jax.tree.map(jnp.negative, pullback(adjoint)), None, None, None)


_midpoint.defvjp(_midpoint_forward, _midpoint_backward)


def _dynamics(basis: FluidBasis, tau, coriolis, viscosity) -> _Dynamics:
    k, h = basis.harmonic_advection.shape[:2]
    damping = 1.0 + 0.5 * tau * viscosity * basis.values  # Crank-Nicolson viscosity; harmonic fields do not diffuse
    return _Dynamics(
        advection=basis.advection,
        advection_by_stream=jnp.transpose(basis.advection, (1, 0, 2)).reshape(k, k * k),
        harmonic_advection_by_field=jnp.transpose(basis.harmonic_advection, (1, 0, 2)).reshape(h, k * k),
        harmonic_advection=basis.harmonic_advection,
        harmonic_exchange=basis.harmonic_exchange,
        inverse=inverse_values(basis.values),
        damping=jnp.concatenate([damping, jnp.ones(h, damping.dtype)]),
        coriolis=coriolis,
        half=0.5 * tau,
    )


def _midpoint_step(dynamics: _Dynamics, state, max_steps, rtol, active):
    """One implicit midpoint step of `(a, c, g)` (module docstring): `(state, counts, converged)` as `_midpoint`."""
    vorticity, harmonic, dye = state
    start = jnp.concatenate([vorticity, harmonic])
    midpoint, counts, converged = _midpoint(dynamics, start, max_steps, rtol, active)
    new_vorticity, new_harmonic = dynamics.split(2.0 * midpoint - start)
    if dye is None:
        return (new_vorticity, new_harmonic, None), counts, converged
    # The dye's step is linear: a Cayley transform of the antisymmetric midpoint transport.
    transport = dynamics.half * dynamics.transport(*dynamics.split(midpoint))
    identity = jnp.eye(transport.shape[0], dtype=transport.dtype)
    new_dye = jnp.linalg.solve(identity - transport, dye + transport @ dye)
    return (new_vorticity, new_harmonic, new_dye), counts, converged


@kernel(static_argnames=("count",))
def _advance(basis: FluidBasis, state, failure: Failure, start, tau, rotation, viscosity, max_steps, rtol, *, count):
    """Steps `start + 1, ..., start + count`: `((state, failure), (state, counts))`, `counts` the most
    fixed-point iterations and Newton steps of one of these steps."""
    dynamics = _dynamics(basis, tau, rotation * basis.coriolis, viscosity)

    def step(carry, k):
        state, failure, most = carry
        # After a failure the flow stops (the failed state is kept): a select, as a branch per step
        # costs as much as the step itself on small states; the stopped steps iterate nothing.
        stopped = failed_before(failure, k)
        new, counts, converged = _midpoint_step(dynamics, state, max_steps, rtol, ~stopped)
        state = jax.tree.map(functools.partial(jnp.where, stopped), state, new)
        outcome = RESULTS.where(converged, finite_outcome(state), RESULTS.max_steps_reached)
        return (state, record(failure, k, outcome), jnp.maximum(most, counts)), None

    (state, failure, most), _ = scan_steps(step, (state, failure, jnp.zeros(2, jnp.int32)), start, count)
    return (state, failure), (state, most)


def _states(basis, state, tau, rotation, viscosity, max_steps, rtol, *, steps, save_every, progress):
    """The saved states (stacked, the initial one first), their chunks' iteration counts `(s, 2)` and the first `Failure`."""

    def chunk(carry, start):
        return _advance(basis, *carry, start, tau, rotation, viscosity, max_steps, rtol, count=save_every)

    start = (state, record(no_failure(), 0, finite_outcome(state)))
    (_, failure), (frames, counts) = run_chunks(
        # Checkpointed chunks: reverse mode keeps one state per chunk and recomputes the chunk's steps.
        chunk if progress else jax.checkpoint(chunk, prevent_cse=False),
        start,
        chunks=steps // save_every,
        every=save_every,
        progress=progress,
        description="euler flow",
    )
    saved = jax.tree.map(lambda first, rest: jnp.concatenate([first[None], rest]), state, frames)
    return saved, jnp.concatenate([jnp.zeros((1, 2), jnp.int32), counts]), failure


@kernel(static_argnames=("steps", "save_every"))
def _run(basis, state, tau, rotation, viscosity, max_steps, rtol, *, steps, save_every):
    """`_states` as one compiled program (the path without a progress bar)."""
    return _states(basis, state, tau, rotation, viscosity, max_steps, rtol, steps=steps, save_every=save_every, progress=False)
