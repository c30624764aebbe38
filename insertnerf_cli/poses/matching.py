"""Progress for COLMAP's feature matching, which reports nothing while it runs (a minute for 100 photos).

pycolmap's matchers release the GIL and write each matched image pair into the database (WAL journal) as they go,
so while the matcher runs a helper thread has the rows of its ``matches`` table counted. The count runs in a child
process: COLMAP's SQLite is linked into pycolmap, and a second SQLite library (Python's) opening
the same file in this process would release COLMAP's POSIX file locks whenever it closes the file
(sqlite.org/howtocorrupt.html, 2.2.1; an in-process reader did read "database disk image is malformed" here).
"""
from __future__ import annotations

import subprocess
import sys
import threading
from functools import partial
from pathlib import Path
from typing import Callable

import pycolmap

from insertnerf_cli.poses.child import run_in_child

POLL_S = 2.5  # how often the database is counted (a child process each time); ticks are rate-limited by the caller
_COUNT_SCRIPT = ("import pathlib, sqlite3, sys\n"
                 "uri = pathlib.Path(sys.argv[1]).resolve().as_uri() + '?mode=ro'\n"
                 "with sqlite3.connect(uri, uri=True, timeout=1.0) as db:\n"
                 "    print(db.execute('SELECT COUNT(*) FROM matches').fetchone()[0])\n")


def exhaustive_pairs(images: int) -> int:
    """Image pairs the exhaustive matcher forms: every pair once."""
    return images * (images - 1) // 2


def sequential_pairs(images: int, overlap: int, quadratic: bool = True) -> int:
    """Image pairs the sequential matcher forms, each image (in name order) with the ones 1, 2, ..., ``overlap``
    ahead, or with ``quadratic`` (COLMAP 3.x/4.x) the ones 1, 2, 4, ..., 2^(overlap-1) ahead instead."""
    offsets = [2 ** k for k in range(overlap)] if quadratic else list(range(1, overlap + 1))
    return sum(images - d for d in offsets if d < images)


def pairs_written(db_path: Path) -> int | None:
    """Rows in the database's ``matches`` table so far, counted by a child process (see the module's note); None
    while it cannot be read (not created yet, locked)."""
    try:
        out = subprocess.run([sys.executable, "-c", _COUNT_SCRIPT, str(db_path)], capture_output=True, text=True,
                             timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    count = out.stdout.strip()
    return int(count) if out.returncode == 0 and count.isdigit() else None


def run_with_progress(match: Callable[[], None], db_path: Path, tick: Callable[[int], None]) -> None:
    """Run ``match`` (a pycolmap matcher call writing into ``db_path``) while a helper thread has the pairs written
    so far counted every POLL_S seconds and passed to ``tick``.

    The matcher runs in a child process (child.run_in_child), so that Ctrl-C stops it within a second.
    """
    stop = threading.Event()

    def poll() -> None:
        while not stop.wait(POLL_S):
            done = pairs_written(db_path)
            if done is not None and not stop.is_set():
                tick(done)

    poller = threading.Thread(target=poll, name="matching-progress", daemon=True)
    poller.start()
    try:
        run_in_child(lambda send: match())
    finally:
        stop.set()
        poller.join()


def match(db_path: Path, matcher: str, images: int, overlap: int, threads: int, start: Callable[[str], None],
          tick: Callable[[int, int], None]) -> str:
    """COLMAP's "exhaustive", "sequential" (``overlap``, quadratic) or "chain" (sequential with ``overlap`` linear:
    each image with the ``overlap`` after it in name order, no long links) matcher over the ``images`` in ``db_path``,
    on the CPU with ``threads``; ``start`` gets the stage's description, ``tick`` (pairs done, pairs) its progress.
    Pairs already in the database count as done (exhaustive after sequential matches only the rest). Returns how
    many pairs the mapper can use, in words."""
    matching = pycolmap.FeatureMatchingOptions(num_threads=threads)
    if matcher == "exhaustive":
        pairs = exhaustive_pairs(images)
        run = partial(pycolmap.match_exhaustive, db_path, matching_options=matching, device=pycolmap.Device.cpu)
    else:
        quadratic = matcher == "sequential"
        pairs = sequential_pairs(images, overlap, quadratic)
        pairing = pycolmap.SequentialPairingOptions(overlap=overlap, quadratic_overlap=quadratic)
        run = partial(pycolmap.match_sequential, db_path, matching_options=matching, pairing_options=pairing,
                      device=pycolmap.Device.cpu)
    done_before = pairs_written(db_path) or 0  # matched by an earlier stage: the rest sets the pace
    left = max(pairs - done_before, 0)
    start(f"{matcher} matcher, {pairs} image pairs" + (f" ({left} not matched yet)" if done_before else ""))
    run_with_progress(run, db_path, lambda done: tick(min(max(done - done_before, 0), left), left))
    with pycolmap.Database.open(db_path) as db:
        _, geometries = db.read_two_view_geometries()
        # The mapper ignores pairs with fewer inliers than this, so only those count as usefully matched.
        min_inliers = pycolmap.IncrementalPipelineOptions().min_num_matches
        useful = sum(len(g.inlier_matches) >= min_inliers for g in geometries)
        return f"{useful} of {db.num_matched_image_pairs()} image pairs share >= {min_inliers} verified matches"
