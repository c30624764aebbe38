"""The `insertnerf` console entry point (``main``); the command group itself is ``cli`` in group.py.

This module imports only the standard library, so that Ctrl-C during the slow start-up (click, then torch
behind the commands) is answered like Ctrl-C inside a command: one line and exit code 130. Only the first
few milliseconds of the interpreter's own start-up lie outside our reach.
"""
from __future__ import annotations

import signal
import sys

from insertnerf_cli.errors import INTERRUPTED, INTERRUPTED_EXIT_CODE
from insertnerf_cli.interrupts import held_interrupts


def __getattr__(name: str) -> object:
    """``from insertnerf_cli.cli.main import cli`` still gives the group (it lives in group.py, see above)."""
    if name == "cli":
        from insertnerf_cli.cli.group import cli

        return cli
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def main() -> None:
    """Run the command line: click's own handling, except that Ctrl-C before a command's body runs (while
    modules import, while options are parsed) prints the same short line as inside a command, exit 130."""
    try:
        with held_interrupts():
            import click

            from insertnerf_cli.cli.group import cli
        try:
            code = cli.main(prog_name="insertnerf", standalone_mode=False)
        except click.ClickException as err:
            err.show()
            code = err.exit_code
        except click.Abort:  # click's name for a Ctrl-C outside a command's body
            raise KeyboardInterrupt from None
    except KeyboardInterrupt:
        print(INTERRUPTED, file=sys.stderr)
        code = INTERRUPTED_EXIT_CODE
    _ignore_interrupts()
    sys.exit(code if isinstance(code, int) else 0)


def _ignore_interrupts() -> None:
    """Ctrl-C off for the interpreter's shutdown: the command has ended and its outputs are final, so a Ctrl-C
    while the thread pools and torch tear down can stop nothing; Python would print it as an 'Exception ignored'
    traceback and exit 0 all the same."""
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread (an embedding caller): its signals are not ours to change
        pass
