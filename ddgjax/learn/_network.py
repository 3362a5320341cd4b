"""A DiffusionNet written with equinox: a worked example of the learning operators, not a framework.

DiffusionNet (Sharp, Attaiki, Crane & Ovsjanikov 2022) learns on surfaces with three per-vertex
ingredients, each discretisation agnostic: a **learned diffusion** per channel (`spectral_diffusion`,
`exp(-lambda t_c)` on the eigenbasis, the time `t_c` a parameter), **spatial gradient features**
(`spatial_gradient_features`: `tanh Re(conj(g) (A g))` of the diffused features' tangent gradients,
invariant to the choice of tangent frames) and a **per-vertex MLP**. A block is

    x_diffused = spectral_diffusion(x, operators, times)
    g          = spatial_gradients(x_diffused, operators)                   # (nv, C, 2)
    x_out      = x + MLP([x, x_diffused, spatial_gradient_features(g, A_re, A_im)])

and `DiffusionNet` is a linear layer in, `n_blocks` blocks, a linear layer out. Everything is an
`equinox.Module`, so `jax.grad` / `optax` train it, `jax.jit` compiles a whole training step, and
`jax.vmap` over stacked (padded) operators runs a batch of meshes of different sizes
(`ddgjax.learn.stack_diffusion_operators`): padded vertices have zero mass and no neighbours, so they
never reach real vertices; their outputs are to be masked out of a loss.

The original is in PyTorch (`diffusion_net.layers.DiffusionNetBlock`); this one uses its defaults where
they matter: times start at 0 and are clamped at `1e-8` (a negative time would make diffusion
explode; the clamp passes the derivative through, so times starting at 0 learn), the MLP has two hidden layers of the block's width, ReLU; no dropout (add `eqx.nn.Dropout`
in a copy of the block where a task needs it).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._errors import check_count
from ._diffusion import spatial_gradient_features, spatial_gradients, spectral_diffusion
from ._operators import DiffusionOperators

#: The smallest diffusion time a block uses (DiffusionNet's clamp): learned times stay >= it.
MIN_TIME = 1e-8


class DiffusionNetBlock(eqx.Module):
    """One DiffusionNet block on `width` channels (module docstring): diffusion, gradient features, MLP, residual.

    Attributes:
        times: `(width,)` the learned diffusion time of each channel (starts at 0; used clamped at `MIN_TIME`,
            with the derivative of the unclamped time).
        gradient_real, gradient_imag: `(width, width)` the learned complex matrix `A` of the gradient features.
        mlp: the per-vertex MLP from `3 width` features (input, diffused, gradient features) to `width`.
    """

    times: Float[Array, " width"]
    gradient_real: Float[Array, "width width"]
    gradient_imag: Float[Array, "width width"]
    mlp: eqx.nn.MLP

    def __init__(self, width: int, *, key: PRNGKeyArray, dtype=None):
        width = check_count("width", width)
        dtype = dtype or jnp.zeros(()).dtype
        real_key, imag_key, mlp_key = jax.random.split(key, 3)
        bound = 1.0 / jnp.sqrt(width)  # PyTorch's default Linear initialisation, as DiffusionNet's
        self.times = jnp.zeros(width, dtype)
        self.gradient_real = jax.random.uniform(real_key, (width, width), dtype, -bound, bound)
        self.gradient_imag = jax.random.uniform(imag_key, (width, width), dtype, -bound, bound)
        self.mlp = eqx.nn.MLP(3 * width, width, width, depth=2, activation=jax.nn.relu, key=mlp_key, dtype=dtype)

    def __call__(self, x: Float[Array, "nv width"], operators: DiffusionOperators) -> Float[Array, "nv width"]:
        """`x + MLP([x, h, tanh Re(conj(grad h) A grad h)])` with `h` the diffusion of `x` for the learned times."""
        # Clamped in value, the identity in derivative: DiffusionNet clamps the parameter itself after each
        # step, so its gradient is taken at the clamped time; a plain maximum would stop times at 0 from learning.
        times = self.times + jax.lax.stop_gradient(jnp.maximum(self.times, MIN_TIME) - self.times)
        diffused = spectral_diffusion(x, operators, times)
        features = spatial_gradient_features(spatial_gradients(diffused, operators), self.gradient_real, self.gradient_imag)
        return x + jax.vmap(self.mlp)(jnp.concatenate([x, diffused, features], axis=-1))


class DiffusionNet(eqx.Module):
    r"""DiffusionNet: a per-vertex linear layer in, `n_blocks` `DiffusionNetBlock`s, a linear layer out.

    $$x \mapsto x + \mathrm{MLP}\bigl(x, \ h_t(x), \ \tanh(\mathrm{Re}(\bar g \, (A g)))\bigr), \qquad h_t(x) = \Phi \operatorname{diag}(e^{-\lambda t}) \Phi^\top M x$$

    `model(x, operators)` maps `(nv, in_channels)` vertex features (positions, heat kernel signatures, ...)
    to `(nv, out_channels)`; `jax.vmap(model)(X, stacked_operators)` runs a padded batch (module docstring).
    Sharp et al. 2022, figure 2 (DiffusionNet's `DiffusionNet(C_in, C_out, C_width=128, N_block=4)`).

    Args:
        in_channels: the number of input features per vertex.
        out_channels: the number of outputs per vertex.
        width: the features per vertex inside the blocks (default 128, keyword-only).
        n_blocks: the number of `DiffusionNetBlock`s (default 4, keyword-only).
        key: a PRNG key for the initial weights (keyword-only).
        dtype: the weights' float dtype (keyword-only; default JAX's default float).

    Examples:
        >>> import jax
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(2)
        >>> operators = ddgjax.learn.diffusion_operators(sphere, 16)
        >>> model = ddgjax.learn.DiffusionNet(3, 2, width=8, n_blocks=2, key=jax.random.key(0))
        >>> model(sphere.vertices, operators).shape
        (162, 2)
    """

    first: eqx.nn.Linear
    blocks: tuple[DiffusionNetBlock, ...]
    last: eqx.nn.Linear

    def __init__(
        self, in_channels: int, out_channels: int, *, width: int = 128, n_blocks: int = 4, key: PRNGKeyArray, dtype=None
    ):
        in_channels, out_channels = check_count("in_channels", in_channels), check_count("out_channels", out_channels)
        keys = jax.random.split(key, check_count("n_blocks", n_blocks) + 2)
        self.first = eqx.nn.Linear(in_channels, width, key=keys[0], dtype=dtype)
        self.blocks = tuple(DiffusionNetBlock(width, key=k, dtype=dtype) for k in keys[1:-1])
        self.last = eqx.nn.Linear(width, out_channels, key=keys[-1], dtype=dtype)

    def __call__(self, x: Float[Array, "nv in_channels"], operators: DiffusionOperators) -> Float[Array, "nv out_channels"]:
        """The per-vertex outputs `(nv, out_channels)`."""
        x = jax.vmap(self.first)(x)
        for block in self.blocks:
            x = block(x, operators)
        return jax.vmap(self.last)(x)
