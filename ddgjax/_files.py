"""Replacing a file atomically: the one write path of `ddgjax.io` and `ddgjax.volume`'s files (nothing lost on failure)."""

from __future__ import annotations

import contextlib
import io
import os
import pathlib
import stat
import tempfile
from collections.abc import Callable

import numpy as np

from ._errors import DDGInputError, first_indices


def finite_host_vertices(name: str, vertices, path: pathlib.Path, hint: str = "") -> np.ndarray:
    """`vertices` as a float64 host array, or `DDGInputError` naming `name`, the non-finite rows and the
    untouched `path` (a save refuses before writing anything); `hint` is added to the remedy."""
    host = np.asarray(vertices, dtype=np.float64)
    bad = ~np.isfinite(host).all(axis=1)
    if bad.any():
        raise DDGInputError(
            f"{name}: {int(bad.sum())} of its {host.shape[0]} vertices have NaN or inf coordinates (vertices "
            f"{first_indices(bad)}), so nothing was written to {str(path)!r}; give them finite positions first{hint}"
        )
    return host


def write_atomically(target: pathlib.Path, write: Callable[[io.BufferedIOBase], None]) -> None:
    """Run `write` on a temporary file beside `target`, flush it to disk and rename it over `target`;
    on any failure remove the temporary file and leave `target` untouched (`ddgjax.io.save_mesh`, `ddgjax.volume.save_tet_mesh`)."""
    try:
        mode = stat.S_IMODE(os.stat(target).st_mode)  # a replaced file keeps its permissions
    except FileNotFoundError:
        mode = 0o666 & ~_umask()  # what `open(target, "w")` would have given a new file
    descriptor, temporary = tempfile.mkstemp(dir=target.parent, prefix=f".{target.stem}.", suffix=target.suffix)
    try:
        with os.fdopen(descriptor, "wb") as handle:
            write(handle)
            os.fchmod(handle.fileno(), mode)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, target)
    except BaseException:  # interrupts too: the temporary file must not outlive the failed write
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise
    _fsync_folder(target.parent)


def _umask() -> int:
    """The process's umask, read without changing it where the system allows (Linux), since setting it
    affects every thread."""
    with contextlib.suppress(OSError, ValueError), open("/proc/self/status", encoding="ascii") as status:
        for line in status:
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    umask = os.umask(0o022)
    os.umask(umask)
    return umask


def _fsync_folder(folder: pathlib.Path) -> None:
    """Make the rename itself durable (POSIX); where a folder cannot be opened or synced, the rename
    is still atomic, only not yet on disk."""
    with contextlib.suppress(OSError):
        descriptor = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)
