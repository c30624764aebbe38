"""User-facing errors: the message is one line that says what happened and what to do next."""
from __future__ import annotations

import errno

# Printed for Ctrl-C wherever it lands (start-up, a command's body); the command exits with 130.
INTERRUPTED = "Interrupted; finished outputs were kept, re-run the same command to continue."
INTERRUPTED_EXIT_CODE = 130


class UserError(Exception):
    """A mistake in the user's input or environment. The CLI prints it as one line and exits non-zero."""


class SceneError(UserError):
    """A scene folder that cannot be read; the message is one line meant for the user."""


# errno -> (what happened to the path, what to do). The path is err.filename when the OS gave one.
_OS_ADVICE = {
    errno.EACCES: ("permission denied", "check its permissions (or run as a user who may use it)"),
    errno.EPERM: ("operation not permitted", "check its permissions (or run as a user who may use it)"),
    errno.EROFS: ("read-only file system", "choose a location on a writable disk"),
    errno.ENOSPC: ("disk full", "free some space or choose another output folder, then re-run"),
    errno.EDQUOT: ("disk quota exceeded", "free some space or choose another output folder, then re-run"),
    errno.EISDIR: ("is a folder where a file was expected", "give a file path instead"),
    errno.ENOTDIR: ("a part of the path is a file, not a folder", "give a path whose parents are folders"),
    errno.ENOENT: ("does not exist", "check the path"),
    errno.EEXIST: ("already exists", "remove it or choose another path"),
    errno.ENAMETOOLONG: ("file name too long", "choose a shorter path"),
    errno.EMFILE: ("too many open files", "raise the limit (ulimit -n) and re-run"),
    errno.EIO: ("input/output error", "check the disk and re-run"),
}


def os_error_message(err: OSError) -> str:
    """One line for an OSError: what failed, on which path, and what to do.

    The path comes from ``err.filename`` (and ``err.filename2`` for moves); writes to an open file carry no
    name, so the message then says only what happened.
    """
    happened, advice = _OS_ADVICE.get(err.errno or 0, (err.strerror or str(err) or type(err).__name__,
                                                        "check the path and re-run"))
    paths = " -> ".join(str(p) for p in (err.filename, err.filename2) if p is not None)
    return f"{happened}: {paths}; {advice}." if paths else f"{happened} ({err.strerror or err}); {advice}."


def first_line(err: BaseException, limit: int = 160) -> str:
    """An exception's message cut to its first non-blank line and ``limit`` characters ("..." marks a cut), its
    type's name when it has none: for quoting a library's error inside a one-line message (pycolmap's failed
    checks carry COLMAP's source position and a long expression, zipfile quotes whole damaged names)."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()] or [type(err).__name__]
    return lines[0] if len(lines[0]) <= limit else lines[0][:limit] + "..."
