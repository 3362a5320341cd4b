"""Replacing a file atomically: the one write path of `ddgjax.io` and `ddgjax.volume`'s files (nothing lost on failure)."""

from __future__ import annotations

import contextlib
import glob
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
    replace_together({target: write})


def replace_together(writes: dict[pathlib.Path, Callable[[io.BufferedIOBase], None]]) -> None:
    """Replace every target of `writes` (path -> a function writing its bytes), all or none.

    Each file is written in full to a temporary file beside its target and flushed to disk before any
    target changes; the renames follow in order. When a later rename fails, the targets already replaced get
    their old bytes back (a hard link to each old file is kept until every rename has succeeded), so a pair
    of files (TetGen's `.node` + `.ele`) is never left half new. A process killed mid-write leaves its
    temporary files behind; they carry the writer's process id, and the next save of the same target
    removes those of processes that no longer run.
    """
    targets = list(writes)
    for target in targets:
        _remove_orphans(target)
    temporaries: dict[pathlib.Path, str] = {}
    kept: dict[pathlib.Path, str | None] = {}  # target -> a link to its old file (None: there was none)
    replaced: list[pathlib.Path] = []
    try:
        for target, write in writes.items():
            temporaries[target] = _written_beside(target, write)
        for target in targets:
            if len(targets) > 1:
                kept[target] = _kept_copy(target)
            os.replace(temporaries[target], target)
            del temporaries[target]
            replaced.append(target)
    except BaseException:  # interrupts too: nothing half new, no temporary file outlives the failed write
        for target in reversed(replaced):
            with contextlib.suppress(OSError):
                if kept[target] is None:
                    os.unlink(target)
                else:
                    os.replace(kept.pop(target), target)
        _unlink_all([*temporaries.values(), *kept.values()])
        raise
    _unlink_all(kept.values())
    for folder in {target.parent for target in targets}:
        _fsync_folder(folder)


def _unlink_all(names) -> None:
    for name in names:
        if name is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(name)


def _written_beside(target: pathlib.Path, write: Callable[[io.BufferedIOBase], None]) -> str:
    """The name of a new temporary file beside `target` holding `write`'s bytes, flushed to disk, with the
    permissions `target` has (or a new file would get)."""
    try:
        mode = stat.S_IMODE(os.stat(target).st_mode)  # a replaced file keeps its permissions
    except FileNotFoundError:
        mode = 0o666 & ~_umask()  # what `open(target, "w")` would have given a new file
    descriptor, temporary = tempfile.mkstemp(dir=target.parent, prefix=_orphan_prefix(target, os.getpid()), suffix=".tmp")
    try:
        with os.fdopen(descriptor, "wb") as handle:
            write(handle)
            os.fchmod(handle.fileno(), mode)
            handle.flush()
            os.fsync(handle.fileno())
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise
    return temporary


def _kept_copy(target: pathlib.Path) -> str | None:
    """A hard link to `target`'s current file under a temporary name (its old bytes, for a rollback), or
    None when there is no such file."""
    if not target.exists():
        return None
    kept = f"{target.parent / _orphan_prefix(target, os.getpid())}{os.urandom(6).hex()}.old"
    try:
        os.link(target, kept)
    except OSError:  # a file system without hard links: a copy
        import shutil

        shutil.copy2(target, kept)
    return kept


def _orphan_prefix(target: pathlib.Path, pid: int) -> str:
    return f".{target.name}.ddgjax-{pid}-"


def _remove_orphans(target: pathlib.Path) -> None:
    """Remove the temporary files a killed save of `target` left (`_written_beside`, `_kept_copy`): those
    whose process id names no running process. Files of a save still running elsewhere stay."""
    with contextlib.suppress(OSError):
        for leftover in target.parent.glob(f".{glob.escape(target.name)}.ddgjax-*-*"):
            pid = leftover.name[len(f".{target.name}.ddgjax-") :].split("-", 1)[0]
            if pid.isdigit() and not _running(int(pid)):
                with contextlib.suppress(OSError):
                    leftover.unlink()


def _running(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):  # another user's process, or a platform without signal 0
        return True
    return True


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
