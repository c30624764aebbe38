"""Write files so that an interrupt or a full disk never leaves a half-written file under the final name.

A failed write (disk full, no permission, read-only disk) becomes a :class:`WriteError`: one line that names the
file and says what to do; the temporary file is removed and a previous file under the final name is untouched.
"""
from __future__ import annotations

import errno
import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from insertnerf_cli.errors import UserError

_DISK_FULL = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}


class WriteError(UserError):
    """A file could not be written (the previous file under that name, if any, is kept).

    ``problem`` is the short reason ("disk full", "permission denied", ...) for callers that phrase their own line.
    """

    def __init__(self, message: str, problem: str = "cannot write") -> None:
        super().__init__(message)
        self.problem = problem


def _os_error(err: BaseException | None) -> OSError | None:
    """The OSError behind ``err``: itself, or one it was raised from or while handling (torch.save wraps a
    full disk in a RuntimeError whose context is the OSError)."""
    seen = 0
    while err is not None and seen < 8:
        if isinstance(err, OSError):
            return err
        err, seen = err.__cause__ or err.__context__, seen + 1
    return None


def write_error(path: Path, err: OSError) -> WriteError:
    """The one-line error for a failed write of ``path``."""
    if err.errno in _DISK_FULL:
        return WriteError(f"disk full at {path}: free space and re-run the same command; the files finished "
                          "before (and any earlier version of this one) are kept.", "disk full")
    reason = err.strerror or type(err).__name__
    return WriteError(f"cannot write {path} ({reason}); check the folder's permissions and free space, then re-run "
                      "the same command (files finished before are kept).", f"cannot write ({reason})")


def _temp_prefix(path: Path) -> str:
    return f".{path.stem}."


def stray_temporaries(path: Path) -> list[Path]:
    """Temporary files of ``path`` that atomic_path left when its process was killed mid-write (the process id
    in their name is gone; a live writer's file is not stray)."""
    if not path.parent.is_dir():
        return []
    stray = []
    for temp in path.parent.glob(f"{_temp_prefix(path)}*.tmp{path.suffix}"):
        pid = temp.name[len(_temp_prefix(path)):].split("-")[0]
        if pid.isdigit() and not process_alive(int(pid)) and temp.is_file():
            stray.append(temp)
    return stray


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (another user's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds.

    The temporary name keeps the final suffix so writers that pick a format from it (cv2, imageio) work.
    Raises:
        WriteError: the temporary file could not be made, written or renamed (e.g. the disk is full).
    """
    path = Path(path)
    tmp_path: Path | None = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        for stray in stray_temporaries(path):  # left by a killed writer of this same file
            stray.unlink(missing_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f"{_temp_prefix(path)}{os.getpid()}-", suffix=f".tmp{path.suffix}",
                                   dir=path.parent)
        os.close(fd)
        tmp_path = Path(tmp)
        # mkstemp makes the file private (0600); give it the permissions a plain open() would have.
        os.chmod(tmp_path, 0o666 & ~_umask())
        yield tmp_path
        os.replace(tmp_path, path)
    except (OSError, RuntimeError) as err:
        cause = _os_error(err)
        if cause is None:
            raise
        raise write_error(path, cause) from None
    finally:
        if tmp_path is not None and tmp_path.exists():
            tmp_path.unlink()


def write_json(path: str | os.PathLike, data: Any) -> None:
    """Write JSON atomically, indented for people to read; a file that already holds exactly this is left as it
    is (a resumed run then needs no free space to restate its settings)."""
    text = json.dumps(data, indent=2) + "\n"
    try:
        if Path(path).read_text() == text:
            return
    except (OSError, UnicodeDecodeError):
        pass
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def _umask() -> int:
    """The process umask (reading it means setting it; it is restored at once)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask
