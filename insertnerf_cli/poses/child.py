"""pycolmap's long calls in a forked child process, so that Ctrl-C stops them within a second.

A pycolmap call (feature extraction, matching, mapping, triangulation) runs in C++ and looks at Python's signals
rarely or not at all: a Ctrl-C during matching waited for the whole matcher, and COLMAP's cancellation token is
only read between blocks of work. A thread cannot be stopped from outside, and leaving one running while the
interpreter exits aborts the process. A child process can be: the call runs in a forked child (which ignores
SIGINT: a terminal's Ctrl-C reaches the whole process group) while the parent waits in short steps, where Python
delivers Ctrl-C at once; the parent then kills the child and the KeyboardInterrupt goes on up (exit 130, the
staging folder removed on the way). What the call writes (the database, models) is in files; its result comes back
through a pipe, with any progress messages it sends on the way.
"""
from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import traceback
from multiprocessing.connection import Connection
from typing import Any, Callable, TypeVar

T = TypeVar("T")
Send = Callable[[Any], None]
POLL_S = 0.1
_PR_SET_PDEATHSIG = 1


class ChildFailed(RuntimeError):
    """The call raised in the child (its message is the exception's first line) or the child died."""


def run_in_child(call: Callable[[Send], T], on_message: Callable[[Any], None] | None = None) -> T:
    """``call(send)``'s result, computed in a forked child; each ``send(value)`` there reaches ``on_message`` here.
    Ctrl-C here kills the child at once and is re-raised. The result must pickle.

    Raises:
        ChildFailed: the call raised in the child (a RuntimeError subclass, as pycolmap's own failures are).
    """
    context = multiprocessing.get_context("fork")
    receive, give = context.Pipe(duplex=False)
    child = context.Process(target=_child_main, args=(call, give), name="pycolmap", daemon=True)
    child.start()
    give.close()
    outcome: tuple[str, Any] | None = None
    try:
        while outcome is None:
            if receive.poll(POLL_S):
                try:
                    kind, value = receive.recv()
                except EOFError:
                    break
                if kind == "message":
                    if on_message is not None:
                        on_message(value)
                else:
                    outcome = (kind, value)
            elif not child.is_alive() and not receive.poll():
                break
    except KeyboardInterrupt:
        child.kill()
        child.join()
        raise
    finally:
        receive.close()
    child.join()
    if outcome is None:
        raise ChildFailed(f"COLMAP's process ended without a result (exit code {child.exitcode})")
    kind, value = outcome
    if kind == "error":
        raise ChildFailed(value)
    return value


def _child_main(call: Callable[[Send], Any], give: Connection) -> None:
    become_child()
    try:
        result = call(lambda value: give.send(("message", value)))
        give.send(("result", result))
    except BaseException as err:  # noqa: BLE001 - every failure goes back to the parent as one line
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        give.send(("error", first))
        traceback.clear_frames(err.__traceback__)
    finally:
        give.close()


def become_child(parent: int | None = None) -> None:
    """Set this process up as a child its parent stops: Ctrl-C is ignored here (a terminal's reaches the whole
    process group; the parent decides, and kills this process), and the kernel kills it when its parent dies.
    With ``parent`` (the pid the parent had), a child whose parent died before that took effect exits at once."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent()
    if parent is not None and os.getppid() != parent:
        os._exit(0)


def _die_with_parent() -> None:
    """Have the kernel kill this process when its parent dies (Linux's PR_SET_PDEATHSIG), so that a parent killed
    with SIGKILL leaves no COLMAP process writing into its removed staging folder. Elsewhere a no-op."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        pass
