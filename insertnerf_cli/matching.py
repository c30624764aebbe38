"""Progress for COLMAP's feature matching, which reports nothing while it runs (a minute for 100 photos).

pycolmap's matchers release the GIL and write each matched image pair into the database (WAL journal) as they go,
so the matcher runs in a worker thread while this thread counts the rows of its ``matches`` table.
"""
from __future__ import annotations

import sqlite3
import threading
from pathlib import Path
from typing import Callable

POLL_S = 1.0  # how often the database is counted; ticks are rate-limited by the caller


def exhaustive_pairs(images: int) -> int:
    """Image pairs the exhaustive matcher forms: every pair once."""
    return images * (images - 1) // 2


def sequential_pairs(images: int, overlap: int, quadratic: bool = True) -> int:
    """Image pairs the sequential matcher forms, each image (in name order) with the ones 1, 2, ..., ``overlap``
    ahead, or with ``quadratic`` (COLMAP 3.x/4.x) the ones 1, 2, 4, ..., 2^(overlap-1) ahead instead."""
    offsets = [2 ** k for k in range(overlap)] if quadratic else list(range(1, overlap + 1))
    return sum(images - d for d in offsets if d < images)


def pairs_written(db_path: Path) -> int | None:
    """Rows in the database's ``matches`` table so far (None while it cannot be read: not created yet, locked)."""
    try:
        with sqlite3.connect(f"file:{db_path}?mode=ro", uri=True, timeout=0.1) as db:
            return int(db.execute("SELECT COUNT(*) FROM matches").fetchone()[0])
    except sqlite3.Error:
        return None


def run_with_progress(match: Callable[[], None], db_path: Path, tick: Callable[[int], None]) -> None:
    """Run ``match`` (a pycolmap matcher call writing into ``db_path``) in a worker thread and call ``tick`` with
    the number of pairs written so far about every POLL_S seconds; re-raise what the matcher raised.

    Ctrl-C cannot stop COLMAP's matcher midway (as when it ran in this thread): the interrupt is raised once the
    matcher has finished, so the caller's cleanup never races with COLMAP writing the database.
    """
    failure: list[BaseException] = []

    def worker() -> None:
        try:
            match()
        except BaseException as err:  # noqa: BLE001 - handed to the calling thread unchanged
            failure.append(err)

    thread = threading.Thread(target=worker, name="colmap-matching", daemon=True)
    thread.start()
    try:
        while thread.is_alive():
            thread.join(POLL_S)
            done = pairs_written(db_path)
            if done is not None and thread.is_alive():
                tick(done)
    except KeyboardInterrupt:
        thread.join()
        raise
    if failure:
        raise failure[0]
