"""One writer per output: an exclusive OS file lock (``fcntl.flock``) on each command's output.

A writer (render, eval --out, train, finetune --out, synth, poses) calls ``lock_output`` after its location checks
and before it writes anything. The lock file is ``OUT/.insertnerf-lock`` for an output folder and
``.NAME.insertnerf-lock`` beside an output file. A second writer of the same output is refused in one line that
names the holder's command and pid.

Why flock: the kernel drops the lock when its holder exits in any way (return, exception, Ctrl-C, SIGKILL, OOM
kill), so a crash never leaves a lock that must be cleared by hand: a leftover file is not a lock. The holder
removes the file (and a folder it created only for it) when it is done; a file left by a killed run is ignored by
every output check (``is_lock_name``) and simply locked again by the next run.

Scope: locks taken inside a function decorated with ``releases_output_locks`` are released when it returns;
others are held until the process exits. Within one process a lock is re-entrant (a nested call of the same
output does not refuse itself).
"""
from __future__ import annotations

import atexit
import errno
import fcntl
import functools
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, TypeVar

from insertnerf_cli.errors import UserError

LOCK_NAME = ".insertnerf-lock"
_SUFFIX = ".insertnerf-lock"
_F = TypeVar("_F", bound=Callable[..., Any])


class OutputLocked(UserError):
    """Another process is writing the same output."""


def is_lock_name(name: str) -> bool:
    """Whether a file name is one of our lock files (never a user's file, never an output)."""
    return name == LOCK_NAME or (name.startswith(".") and name.endswith(_SUFFIX))


def lock_file(out: Path, is_dir: bool = True) -> Path:
    """Where the lock of the output ``out`` lives: inside an output folder, beside an output file."""
    out = Path(os.path.abspath(out))
    return out / LOCK_NAME if is_dir else out.parent / f".{out.name}{_SUFFIX}"


@dataclass
class _Held:
    fd: int
    created: list[Path]  # folders made for the lock file, deepest first: removed on release if left empty
    depth: int = 1


@dataclass
class _State:
    held: dict[Path, _Held] = field(default_factory=dict)
    scopes: list[list[Path]] = field(default_factory=list)


_STATE = _State()


def lock_output(out: str | os.PathLike, owner: str, is_dir: bool = True) -> None:
    """Take the exclusive lock of the output ``out`` for the command ``owner`` ("render", ...).

    Creates the output folder (or an output file's folder) when missing. Held until the innermost enclosing
    ``releases_output_locks`` function returns, else until the process exits.

    Raises:
        OutputLocked: another process holds it (the message names its command and pid).
    """
    path = lock_file(Path(out), is_dir)
    key = path.resolve()
    if key in _STATE.held:
        _STATE.held[key].depth += 1
    else:
        _STATE.held[key] = _acquire(path, Path(out), owner)
    (_STATE.scopes[-1] if _STATE.scopes else _PROCESS_SCOPE).append(key)


def releases_output_locks(func: _F) -> _F:
    """Release, when ``func`` returns or raises, the output locks taken while it ran."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        _STATE.scopes.append([])
        try:
            return func(*args, **kwargs)
        finally:
            for key in reversed(_STATE.scopes.pop()):
                _release(key)

    return wrapper  # type: ignore[return-value]


_PROCESS_SCOPE: list[Path] = []


@atexit.register
def _release_process_scope() -> None:
    for key in reversed(_PROCESS_SCOPE):
        _release(key)
    _PROCESS_SCOPE.clear()


def _make_folders(folder: Path) -> list[Path]:
    """mkdir -p ``folder``; returns the folders it created, deepest first."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    for made in reversed(missing):
        try:
            made.mkdir()
        except FileExistsError:
            pass
    return missing


def _acquire(path: Path, out: Path, owner: str) -> _Held:
    for _ in range(20):  # each retry follows a holder that removed its file between our open and our lock
        created = _make_folders(path.parent)
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except FileNotFoundError:  # a finishing holder removed the folder it had created: make it again
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise OutputLocked(f"{out} is being written by another insertnerf {holder}; wait for it to finish "
                               "(or stop it), or choose another output.") from None
        except OSError as err:
            os.close(fd)
            if err.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                raise UserError(f"cannot lock {path}: the file system of {out} does not support file locks "
                                f"({err.strerror}); choose an output on a local disk.") from None
            raise
        if _same_file(fd, path):
            _write_holder(fd, owner)
            return _Held(fd, created)
        os.close(fd)  # we locked a file its holder had already removed: lock the current one
    raise UserError(f"could not lock {path}: other processes keep replacing it; re-run.")


def _write_holder(fd: int, owner: str) -> None:
    """Write "PID COMMAND" for a refused writer to quote. On a full disk the lock holds without it: the command
    then meets the full disk where it writes its outputs, with the message that names them."""
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()} {owner}\n".encode(), 0)
    except OSError as err:
        if err.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.stat(path).st_ino == os.fstat(fd).st_ino
    except FileNotFoundError:
        return False


def _holder(fd: int) -> str:
    """"render (pid 123)" from a held lock file; its holder writes it just after locking, so wait a moment."""
    for _ in range(20):
        fields = os.pread(fd, 200, 0).decode("utf-8", "replace").split()
        if len(fields) >= 2 and fields[0].isdigit():
            return f"{fields[1]} (pid {fields[0]})"
        time.sleep(0.01)
    return "command (pid unknown)"


def _release(key: Path) -> None:
    held = _STATE.held.get(key)
    if held is None:
        return
    held.depth -= 1
    if held.depth > 0:
        return
    del _STATE.held[key]
    try:
        if _same_file(held.fd, key):
            key.unlink()  # while still locked: a waiter that opened it re-checks and locks the new file
    except OSError as err:  # a read-only or vanished folder: the lock itself still goes with the fd
        print(f"note: could not remove the lock file {key}: {err.strerror}", file=sys.stderr)
    os.close(held.fd)
    for folder in held.created:
        try:
            folder.rmdir()  # only if the run wrote nothing else there
        except OSError:
            break
