"""How ddgjax compiles its own kernels: `jax.jit`, plus XLA:CPU options where they are measured to help.

XLA:CPU (jax 0.10) hands some fusions to the YNNPACK library once the arrays pass a size: the
reductions over a short axis that geometry is made of (`sum(v * v, axis=-1)` for a length or a dot
product of 2- or 3-vectors) become `__ynn_fusion` kernels that run several times slower than XLA's
own loops (figures in benchmarks/README.md). Below ~2,000 elements XLA emits none, so small inputs
are unchanged. The empty list `xla_cpu_experimental_ynn_fusion_type=""` turns them off.

JAX accepts compiler options only on a top-level `jit`, not on one nested in another
transformation, so `kernel` keeps the plain `jax.jit` too: a call made outside any
transformation on a CPU backend runs the tuned program; under a caller's `jit` / `grad` / `vmap`
the kernel is traced into the caller's program and the caller's settings apply
(`cpu_compiler_options()` gives a user's own `jit` the same; README, conventions). An option this
jaxlib does not know is left out (checked once per process), so an upgrade cannot break a kernel.

Memory: every XLA executable holds 1.5-4 MB (its machine code and runtime, whatever its size), and
`jax.jit` keeps each one for the life of the jitted function (up to thousands per function). A
stream of meshes of new sizes would add programs forever, so a kernel keeps the programs of its
`PROGRAMS_PER_KERNEL` most recently used argument signatures, and compiles each from a fresh
wrapper of the function: JAX's own caches are keyed weakly on the function, so a program dropped
from this bound is freed (figures: benchmarks/README.md, "Memory over a stream of meshes"). One
mesh used many times keeps its programs; only a signature unused for that many newer ones pays a
compilation again. Tracing a program also leaves, in JAX 0.10's trace cache (unbounded, weakly
keyed on the traced function), one jaxpr per `jnp` helper (`multiply`, `where`, ...) and nested
kernel per shape: functions that live as long as the process, so these entries never went (45-70
per new mesh size, 5-17 kB each: benchmarks/README.md). Once a program is lowered its trace is not
needed, so the functions whose entries that lowering added are evicted from the cache
(`_forget_traces`): a later trace of them costs microseconds, and compiled programs, JAX's and the
user's, are untouched.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import inspect
import weakref
from collections.abc import Callable, Mapping

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.core import find_top_trace

from . import _program_store
from ._domain import Domain, domain_for_parameter
from ._errors import DDGInputError

#: Options for every kernel compiled on CPU (module docstring).
CPU_OPTIONS: Mapping[str, str] = {"xla_cpu_experimental_ynn_fusion_type": ""}

#: Compiled programs each kernel keeps, one per argument signature, least recently used dropped (module docstring).
PROGRAMS_PER_KERNEL = 8

#: Every kernel made by `kernel`, for `clear_programs`.
_KERNELS: weakref.WeakSet = weakref.WeakSet()


def clear_programs() -> None:
    """Drop every kernel's compiled programs kept in memory (with `jax.clear_caches()`: a process as if new)."""
    for wrapper in list(_KERNELS):
        wrapper._clear_programs()


def at_top_level() -> bool:
    """True outside every JAX transformation (no `jit`, `grad`, `vmap` is tracing this call)."""
    # The evaluation trace is the bottom of JAX's trace stack; any transformation replaces it.
    return type(find_top_trace(())).__name__ == "EvalTrace"


@functools.cache
def _known(name: str, value: str) -> bool:
    """Whether this jaxlib's XLA:CPU accepts the compiler option (one tiny compile per option and process)."""
    try:
        jax.jit(lambda x: x + 1, compiler_options={name: value}).lower(np.float32(0)).compile()
    except Exception:  # XLA refuses an unknown option or value with INVALID_ARGUMENT
        return False
    return True


# `extra` is annotated loosely on purpose: a malformed value gets this function's own `DDGInputError`
# (naming the argument) rather than a run-time type-checker's message.
def cpu_compiler_options(*, extra: object = None) -> dict[str, str]:
    """XLA:CPU compiler options ddgjax compiles its own kernels with, for a `jax.jit` of your own.

    `jax.jit(f, compiler_options=ddgjax.cpu_compiler_options())` compiles `f` as ddgjax compiles its
    kernels on CPU: without YNNPACK library fusions, which make the short reductions of geometry
    (lengths, dot products of 2- and 3-vectors) several times slower once arrays pass ~2,000
    elements (module docstring; benchmarks/README.md). Same
    effect for every `jit` of a process: `XLA_FLAGS=--xla_cpu_experimental_ynn_fusion_type=` set
    before JAX starts. Options the installed jaxlib does not accept are left out, so the result is
    always safe to pass (and may be empty).
    Reference: XLA's debug options (`xla/debug_options_flags.cc`, `xla_cpu_experimental_ynn_fusion_type`).

    Args:
        extra: options of your own to add, a mapping of option names to string values as
            `jax.jit(..., compiler_options=...)` takes them (keyword-only; default `None`, none); filtered
            like ddgjax's, and taking precedence over them on a shared name.

    Returns:
        A new `dict` of option names to string values that the installed jaxlib accepts (possibly empty).

    Raises:
        DDGInputError: `extra` is not a mapping of strings to strings.
    """
    if extra is not None and (
        not isinstance(extra, Mapping) or not all(isinstance(item, str) for pair in extra.items() for item in pair)
    ):
        raise DDGInputError(f"extra: expected a mapping of option names to string values, got {extra!r}")
    options = {**CPU_OPTIONS, **(extra or {})}
    return {name: value for name, value in options.items() if _known(name, value)}


def kernel(
    function: Callable | None = None,
    *,
    static_argnames: tuple[str, ...] = (),
    requires_orientation: str | None = None,
    extra_cpu_options: Callable[..., Mapping[str, str]] | None = None,
):
    """The one way ddgjax compiles a kernel: `jax.jit` with static arguments by name, meshes handled here.

    - Static arguments are named (`static_argnames`), never numbered.
    - The argument types are checked before tracing: a first parameter named as a `Domain` subclass
      declares (`mesh` for `ddgjax.Mesh`, `tet_mesh` for `ddgjax.volume.TetMesh`, `curve` for
      `ddgjax.curves.Curve`, `batch` for `ddgjax.batch.MeshBatch`) must be one (`DDGInputError`
      saying how to make one, rather than an `AttributeError` from inside the trace).
    - Options are keyword-only: too many positional arguments get Python's `TypeError` naming them.
    - Every `Domain` argument is passed as `domain.for_kernel(...)`: a mesh's static connectivity is not
      part of the cache key, so one program serves every mesh of the same array shapes, and eager
      calls run one compiled program instead of hundreds of op-by-op dispatches. Host work that needs
      the topology (storage plans, orientation checks) runs before the kernel; plans are passed in
      as arguments. `requires_orientation` (the operation's name for the error) checks each mesh's
      orientation first (`Mesh.for_kernel`); a kernel whose body calls an
      orientation-requiring kernel declares it too.
    - A call outside every transformation runs a program of the kernel's bounded cache: one per
      argument signature (shapes, dtypes, static values), the `PROGRAMS_PER_KERNEL` most recently
      used kept (module docstring). On CPU it compiles with `CPU_OPTIONS` (module docstring);
      `extra_cpu_options(*args, **kwargs)`, if given, adds options chosen per call (e.g. from a
      static shape), part of the signature. Under a caller's `jit` / `grad` / `vmap` the kernel is
      traced into the caller's program and the caller's settings apply.

    The wrapper's `_cache_size()` counts its compiled programs, as `jax.jit`'s does.
    """
    if function is None:
        return functools.partial(
            kernel,
            static_argnames=static_argnames,
            requires_orientation=requires_orientation,
            extra_cpu_options=extra_cpu_options,
        )
    plain = jax.jit(function, static_argnames=static_argnames)
    programs: collections.OrderedDict[tuple, Callable] = collections.OrderedDict()
    parameters = inspect.signature(function).parameters.values()
    first = next(iter(parameters)).name if parameters else None
    positional = sum(parameter.kind in (parameter.POSITIONAL_ONLY, parameter.POSITIONAL_OR_KEYWORD) for parameter in parameters)
    keywords = ", ".join(f"{parameter.name}=..." for parameter in parameters if parameter.kind == parameter.KEYWORD_ONLY)
    # Where each static argument sits when passed by position (None: keyword-only).
    index = {parameter.name: i for i, parameter in enumerate(parameters) if parameter.kind != parameter.KEYWORD_ONLY}
    static_positions = {name: index.get(name) for name in static_argnames}

    @functools.wraps(function)
    def call(*args, **kwargs):
        if len(args) > positional:  # Python's own message, naming the options, rather than jit's about static arguments
            hint = f"; pass its options by keyword: {function.__name__}(..., {keywords})" if keywords else ""
            raise TypeError(f"{function.__name__}() takes {positional} positional argument(s) but {len(args)} were given{hint}")
        domain = domain_for_parameter(first)
        if args and domain is not None:
            args = (domain.require(first, args[0]), *args[1:])
        args = tuple(_prepare(arg, requires_orientation) for arg in args)
        kwargs = {name: _prepare(arg, requires_orientation) for name, arg in kwargs.items()}
        if not at_top_level() or jax.config.jax_disable_jit:  # traced into the caller's program, or run op by op
            return plain(*args, **kwargs)
        on_cpu = jax.default_backend() == "cpu"
        extra = tuple(sorted(extra_cpu_options(*args, **kwargs).items())) if extra_cpu_options and on_cpu else ()
        signature, dynamic = _signature(args, kwargs, static_positions)
        key = (signature, extra)
        program = programs.get(key)
        if program is None:
            options = cpu_compiler_options(extra=dict(extra)) if on_cpu else {}
            program = programs[key] = _program(function, static_positions, options, key, args, kwargs, dynamic)
            if len(programs) > PROGRAMS_PER_KERNEL:
                programs.popitem(last=False)
        else:
            programs.move_to_end(key)
        return program(*dynamic[0], **dynamic[1])

    call._cache_size = lambda: plain._cache_size() + len(programs)
    call._clear_programs = programs.clear
    _KERNELS.add(call)
    return call


def _program(function: Callable, static_positions, options: dict[str, str], key: tuple, args, kwargs, dynamic) -> Callable:
    """The compiled program of `function` for one argument signature, called with the dynamic arguments only.

    Read from ddgjax's program store when it holds one (no tracing, lowering or compiling), else
    compiled ahead of time here and written there (`ddgjax._program_store`). In a process with
    several devices it is a `jax.jit` of its own, which places committed arguments as JAX does.
    """
    jitted = jax.jit(_fresh(function), static_argnames=tuple(static_positions), compiler_options=options or None)
    if jax.device_count() != 1:
        return _with_static_arguments(jitted, args, kwargs, static_positions)
    name = f"{function.__module__}.{function.__qualname__}"
    entry = _program_store.entry_key(name, key, options) if _program_store.switched_on() else None
    if entry is not None:
        stored = _program_store.load(entry, jax.tree_util.tree_structure(dynamic))
        if stored is not None:
            return stored
    traced_before = _trace_counts()
    lowered = jitted.lower(*args, **kwargs)
    _forget_traces(traced_before)
    return _program_store.compile_and_save(entry, lowered)


def _trace_caches() -> tuple:
    """JAX's caches of traced jaxprs keyed weakly on the traced function (empty where this JAX has none)."""
    caches = []
    with contextlib.suppress(ImportError, AttributeError):
        from jax._src import pjit
        from jax._src.interpreters import partial_eval

        caches = [partial_eval.trace_to_jaxpr, pjit._infer_params_cached]
    return tuple(cache for cache in caches if hasattr(cache, "cache_keys") and hasattr(cache, "evict_weakref"))


def _trace_counts() -> collections.Counter:
    """How many entries JAX's trace caches hold per traced function (`_forget_traces`)."""
    counts: collections.Counter = collections.Counter()
    for cache in _trace_caches():
        for key in cache.cache_keys():
            function = key[0]() if key and isinstance(key[0], weakref.ref) else None
            if function is not None:
                counts[function] += 1
    return counts


def _forget_traces(before: collections.Counter) -> None:
    """Evict from JAX's trace caches every function that gained entries since `before` (module docstring: memory)."""
    after = _trace_counts()
    for function, count in after.items():
        if count > before.get(function, 0):
            for cache in _trace_caches():
                cache.evict_weakref(function)


def device_array(x, dtype=None) -> jax.Array:
    """`jnp.asarray(x, dtype)` that compiles nothing: a host array is transferred with `jax.device_put`.

    JAX 0.10's `jnp.asarray` of a NumPy array runs a compiled `stage` program, one per shape and
    dtype, kept for the life of the process (module docstring: memory); JAX arrays and tracers go
    through `jnp.asarray` unchanged. Host values get JAX's canonical dtype (float32 without x64).
    """
    if isinstance(x, (jax.Array, jax.core.Tracer)) and (dtype is None or x.dtype == dtype):
        return x  # what `jnp.asarray` returns, without its dispatch (an eager call makes several)
    if isinstance(x, (jax.Array, jax.core.Tracer)) or np.ndim(x) == 0:  # scalars keep JAX's weak typing
        return jnp.asarray(x, dtype)
    host = np.asarray(x, dtype)
    return jax.device_put(host.astype(jax.dtypes.canonicalize_dtype(host.dtype), copy=False))


def _with_static_arguments(jitted: Callable, args: tuple, kwargs: dict, static_positions: dict[str, int | None]) -> Callable:
    """`jitted` called with the dynamic arguments only, the static ones of `args` / `kwargs` put back in place."""
    positions = sorted(position for position in static_positions.values() if position is not None and position < len(args))
    static_keywords = {name: kwargs[name] for name in static_positions if name in kwargs}

    def program(*dynamic_args, **dynamic_kwargs):
        full = list(dynamic_args)
        for position in positions:
            full.insert(position, args[position])
        return jitted(*full, **static_keywords, **dynamic_kwargs)

    return program


def _fresh(function: Callable) -> Callable:
    """A new function object calling `function`: the weak key under which JAX caches one program (module docstring)."""

    @functools.wraps(function)
    def program(*args, **kwargs):
        return function(*args, **kwargs)

    return program


def _signature(args: tuple, kwargs: dict, static_positions: dict[str, int | None]) -> tuple[tuple, tuple]:
    """What selects a compiled program (the argument tree, each leaf's shape, dtype and weak type, the static
    values), and the dynamic arguments `(args, kwargs)` without the static ones: what a compiled program takes."""
    static = tuple(
        (name, kwargs[name] if name in kwargs else args[position])
        for name, position in static_positions.items()
        if name in kwargs or (position is not None and position < len(args))
    )
    positions = {position for position in static_positions.values() if position is not None}
    dynamic = (
        tuple(arg for position, arg in enumerate(args) if position not in positions),
        {name: value for name, value in kwargs.items() if name not in static_positions},
    )
    leaves, tree = jax.tree_util.tree_flatten(dynamic)
    avals = tuple(
        (getattr(leaf, "shape", None), getattr(leaf, "dtype", type(leaf)), getattr(leaf, "weak_type", False)) for leaf in leaves
    )
    return (tree, static, avals), dynamic


def _prepare(argument, requires_orientation: str | None):
    """A `Domain` as its kernels trace it (`Domain.for_kernel`); anything else unchanged."""
    return argument.for_kernel(requires_orientation) if isinstance(argument, Domain) else argument
