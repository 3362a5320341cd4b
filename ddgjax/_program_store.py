"""Compiled kernels kept across processes: ddgjax's own on-disk store of its kernels' executables.

A fresh process that calls a ddgjax kernel on arrays of a shape seen before loads the compiled
program from disk instead of tracing, lowering and compiling it again. Unlike JAX's persistent
compilation cache (keyed on the lowered program, so every call still traces and lowers, and only
active where the user configured it), this store is keyed *before* tracing, on what selects a
kernel's program (`ddgjax._compile`): the kernel's name, the argument tree, each leaf's shape,
dtype and weak type, the static values and the compiler options, plus a fingerprint of everything
that could change the program (ddgjax's own source, the versions of JAX, jaxlib and the libraries
traced into kernels, JAX's tracing configuration, `XLA_FLAGS`, the backend, its devices and the
host CPU). It never touches JAX's global configuration.

Where: `$DDGJAX_CACHE_DIR/programs` when that variable is set, else `$XDG_CACHE_HOME/ddgjax/programs`
(`~/.cache/ddgjax/programs`). `DDGJAX_COMPILATION_CACHE=0` (or `false`, `no`, `off`) turns it off;
the variables are read at each compilation, so they can be changed at run time.

What is not stored: programs that hold a host callback (`jax.pure_callback`: SciPy, pyamg; the
executable would point into this process's memory, which is why JAX's own cache refuses them too),
kernels defined outside ddgjax's source or inside a function (neither their code nor their closures
are in the key), static values without a stable text form, and processes with several devices (a
program is compiled for one device).

Failure: an entry that does not load (a truncated file, another jaxlib, a pickle of another layout)
is compiled again and overwritten; a directory that cannot be written leaves compiled programs in
memory only. Either is said once per process with a `UserWarning`, never raised. Entries are written
to a temporary file and renamed into place, so two processes writing the same entry leave a valid one.
"""

from __future__ import annotations

import contextlib
import copyreg
import functools
import hashlib
import importlib.metadata
import io
import os
import pathlib
import pickle
import platform
import sys
import tempfile
import warnings

import jax
from jax.experimental import serialize_executable

#: Environment variable that turns the store (and the CLI's use of JAX's cache) off when set to one of `_OFF`.
SWITCH_VARIABLE = "DDGJAX_COMPILATION_CACHE"
#: Environment variable naming the folder of ddgjax's caches (default: `$XDG_CACHE_HOME/ddgjax`).
DIRECTORY_VARIABLE = "DDGJAX_CACHE_DIR"
_OFF = ("0", "false", "no", "off")
# Libraries whose code is traced into ddgjax's kernels: a new release may change a program.
_TRACED_LIBRARIES = ("jax", "jaxlib", "equinox", "lineax", "optimistix", "jaxtyping", "sparsax")
_FORMAT = 1  # bumped when the layout of an entry changes


def switched_on() -> bool:
    """False when `DDGJAX_COMPILATION_CACHE` says off (`0`, `false`, `no`, `off`)."""
    return os.environ.get(SWITCH_VARIABLE, "").strip().lower() not in _OFF


def cache_root() -> pathlib.Path:
    """`$DDGJAX_CACHE_DIR`, else `$XDG_CACHE_HOME/ddgjax` (`~/.cache/ddgjax` when unset or relative)."""
    explicit = os.environ.get(DIRECTORY_VARIABLE, "")
    if explicit:
        return pathlib.Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME", "")
    if not os.path.isabs(base):
        base = os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "ddgjax"


def programs_directory() -> pathlib.Path:
    """The folder of the store's entries (module docstring)."""
    return cache_root() / "programs"


def entry_key(name: str, signature: tuple, options: dict[str, str]) -> str | None:
    """The file name of a kernel's program for one argument signature, or None when it must not be stored.

    `signature` is `ddgjax._compile`'s in-memory key: the argument tree, the static values and each
    leaf's shape and dtype (module docstring lists what else goes in).
    """
    if not name.startswith("ddgjax.") or "<locals>" in name or jax.device_count() != 1 or jax.config.jax_disable_jit:
        return None  # only ddgjax's own source is in the fingerprint; closures are not in the key
    text = repr((name, signature, sorted(options.items()), _trace_context()))
    if " at 0x" in text:  # an object whose repr is its address: no stable key across processes
        return None
    return hashlib.sha256((_fingerprint() + text).encode()).hexdigest()


def load(key: str, in_tree) -> jax.stages.Compiled | None:
    """The stored program under `key` for arguments of tree `in_tree`, or None (missing, or failed to load)."""
    path = programs_directory() / f"{key}.bin"
    try:
        payload = path.read_bytes()
    except OSError:
        return None
    try:
        version, executable, out_tree = pickle.loads(payload)
        if version != _FORMAT:
            return None
        _bind_host_kernels()
        return serialize_executable.deserialize_and_load(executable, in_tree, out_tree)
    except Exception as error:  # any bad entry (truncated, another jaxlib or CPU) is compiled again, never trusted
        _warn_once(
            "load", f"ddgjax: a stored compiled program did not load and is compiled again ({type(error).__name__}: {error})"
        )
        return None


@functools.cache
def _bind_host_kernels() -> None:
    """Bind the foreign kernels a stored program may call before running one read from disk.

    JAX binds LAPACK's lazily, when it first lowers a linear-algebra operation (`jax._src.lax.linalg`'s
    `prepare_lapack_call`); a program read from disk is never lowered, and one calling LAPACK
    (`eigh`, `cholesky`, `svd`, `solve`) in a process that lowered none would call an unbound kernel
    and crash. `jax.export` binds them the same way for the programs it deserialises. `sparsax`
    registers its CHOLMOD targets when imported.
    """
    from jax._src.lax import linalg

    linalg.initialize_lapack()
    with contextlib.suppress(ImportError):  # the `cholmod` extra: absent, no stored program calls it
        import sparsax  # noqa: F401


def compile_and_save(key: str | None, lowered: jax.stages.Lowered) -> jax.stages.Compiled:
    """`lowered.compile()`, stored under `key` (None: not stored) unless JAX's own persistent cache served it.

    An XLA:CPU executable that JAX loaded from its persistent compilation cache serializes without the
    code of some of its functions (jaxlib 0.10: the entry loads, then its first call fails with
    "Function ... not found"); only programs compiled here are stored, so a process whose JAX cache
    answered leaves the entry to the next one that compiles it.
    """
    hits = _JAX_CACHE_HITS[0]
    compiled = lowered.compile()
    if key is not None and _JAX_CACHE_HITS[0] == hits:
        save(key, lowered, compiled)
    return compiled


def _count_jax_cache_hits(event: str, **_) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _JAX_CACHE_HITS[0] += 1


_JAX_CACHE_HITS = [0]
jax.monitoring.register_event_listener(_count_jax_cache_hits)


def save(key: str, lowered: jax.stages.Lowered, compiled: jax.stages.Compiled) -> None:
    """Store `compiled` under `key` unless it holds a host callback; any failure is one warning, then ignored."""
    if _host_callbacks(lowered):
        return
    try:
        executable, in_tree, out_tree = serialize_executable.serialize(compiled)
        payload = _dumps((_FORMAT, executable, out_tree))
        if pickle.loads(payload)[2] != out_tree:  # a tree that does not survive pickling is not stored
            return
    except Exception:  # not serialisable (an executable kind or a pytree node without pickling): memory only
        return
    directory = programs_directory()
    temporary = None
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=directory, prefix=f".{key}.", delete=False) as handle:
            temporary = handle.name
            handle.write(payload)
        os.replace(temporary, directory / f"{key}.bin")  # atomic: a reader sees the old entry or the whole new one
    except OSError as error:
        if temporary is not None:
            with contextlib.suppress(OSError):
                os.unlink(temporary)
        _warn_once("save", f"ddgjax: compiled programs are kept in memory only: cannot write {directory} ({error})")


def _host_callbacks(lowered: jax.stages.Lowered) -> bool:
    """Whether the program calls back into this Python process (JAX's own cache refuses those too)."""
    compile_args = getattr(getattr(lowered, "_lowering", None), "compile_args", None)
    if not isinstance(compile_args, dict):
        return True  # a JAX whose lowering we cannot inspect: assume the worst, store nothing
    return bool(compile_args.get("host_callbacks"))


def _trace_context() -> tuple:
    """JAX's configuration that changes a trace (x64, promotion rules, ...): the part of `jax.jit`'s own cache key."""
    from jax._src import config

    return tuple(type(item).__name__ if " at 0x" in repr(item) else item for item in config.trace_context())


@functools.cache
def _fingerprint() -> str:
    """Everything outside the call that could change a compiled program (module docstring), once per process."""
    source = hashlib.sha256()
    package = pathlib.Path(__file__).parent
    for path in sorted(package.rglob("*.py")):
        source.update(str(path.relative_to(package)).encode())
        source.update(path.read_bytes())
    versions = []
    for library in _TRACED_LIBRARIES:
        try:
            versions.append((library, importlib.metadata.version(library)))
        except importlib.metadata.PackageNotFoundError:
            versions.append((library, None))
    device = jax.devices()[0]
    backend = (device.platform, device.client.platform_version, device.device_kind)
    return repr(
        (_FORMAT, source.hexdigest(), versions, sys.version_info[:2], backend, os.environ.get("XLA_FLAGS", ""), _host_cpu())
    )


def _host_cpu() -> str:
    """The host CPU's model and instruction-set flags: XLA:CPU compiles for the features it finds."""
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            lines = [line for line in cpuinfo.read().splitlines() if line.startswith(("model name", "flags", "Features"))]
        return hashlib.sha256("\n".join(sorted(set(lines))).encode()).hexdigest()
    except OSError:
        return f"{platform.machine()} {platform.processor()}"


def _eqx_missing():
    from equinox._module._flatten import MISSING

    return MISSING


def _dumps(value) -> bytes:
    """`pickle.dumps` that keeps equinox's MISSING sentinel a singleton (it sits in `eqx.Module` tree definitions)."""
    buffer = io.BytesIO()
    pickler = pickle.Pickler(buffer)
    with contextlib.suppress(ImportError, AttributeError):
        pickler.dispatch_table = {**copyreg.dispatch_table, type(_eqx_missing()): lambda _: (_eqx_missing, ())}
    pickler.dump(value)
    return buffer.getvalue()


_warned: set[str] = set()


def _warn_once(kind: str, message: str) -> None:
    if kind not in _warned:
        _warned.add(kind)
        warnings.warn(message, stacklevel=4)
