"""Ctrl-C held while slow modules import (used by the entry point in cli/main.py and the command group in cli/group.py).

Standard library only: the entry point imports this before anything slow, and it must load in a few milliseconds.
"""
from __future__ import annotations

import signal


class held_interrupts:  # noqa: N801 - used like a function: `with held_interrupts():`
    """Hold Ctrl-C while modules import, then raise it as KeyboardInterrupt once they have.

    An interrupt in the middle of importing an extension module (torch, pycolmap: pybind11) aborts the whole
    process with a C++ error instead of raising KeyboardInterrupt; nothing useful happens in between anyway.
    (A class rather than contextlib, and no typing import: this module must load in a few milliseconds.)
    """

    def __enter__(self) -> None:
        self.hits: list[int] = []
        try:
            self.previous = signal.signal(signal.SIGINT, lambda signum, frame: self.hits.append(signum))
        except ValueError:  # not the main thread (e.g. a test runner's worker): signals are not ours to handle
            self.previous = None

    def __exit__(self, *exc_info: object) -> None:
        if self.previous is not None:
            signal.signal(signal.SIGINT, self.previous)
        if self.hits and exc_info[0] is None:
            raise KeyboardInterrupt
