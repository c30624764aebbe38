"""Progress of `insertnerf poses` by stage, pycolmap's log level, and the threads it may use (no pycolmap model
is built here: estimate.py)."""
from __future__ import annotations

import os
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator

import pycolmap

Report = Callable[[str], None]


@dataclass(frozen=True)
class StageTime:
    name: str
    seconds: float


class Stages:
    """One line when a stage starts, one when it ends (counts, elapsed seconds), throttled counts in between."""

    def __init__(self, report: Report, total: int) -> None:
        self.report, self.total, self.index, self.times = report, total, 0, []
        self._name, self._t0, self._last_tick = "", 0.0, 0.0

    def start(self, name: str, detail: str) -> None:
        self.index += 1
        self._name, self._t0 = name, time.perf_counter()
        self._last_tick = self._t0
        self.report(f"[{self.index}/{self.total}] {name}: {detail}")

    def tick(self, done: int, total: int, what: str, every_s: float = 5.0) -> None:
        now = time.perf_counter()
        if now - self._last_tick < every_s or done <= 0:
            return
        self._last_tick = now
        elapsed = now - self._t0
        eta = elapsed / done * max(total - done, 0)
        self.report(f"      {done}/{total} {what}, {elapsed:.0f} s elapsed, ~{eta:.0f} s left")

    def done(self, detail: str) -> None:
        seconds = time.perf_counter() - self._t0
        self.times.append(StageTime(self._name, seconds))
        self.report(f"      {detail} ({seconds:.1f} s)")


@contextmanager
def pycolmap_log(verbose: bool) -> Iterator[None]:
    """Silence pycolmap's glog unless verbose (our own messages report its failures); restore the level after."""
    previous = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 0 if verbose else 3
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = previous


def num_threads(requested: int) -> int:
    if requested > 0:
        return requested
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
