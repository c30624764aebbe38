"""Progress of COLMAP's matching: the pair counts it forms, and counting its database while it runs."""
from __future__ import annotations

import sqlite3
import time
from pathlib import Path

import pytest

from insertnerf_cli.poses.matching import exhaustive_pairs, pairs_written, run_with_progress, sequential_pairs


def test_pair_counts() -> None:
    assert exhaustive_pairs(8) == 28 and exhaustive_pairs(1) == 0
    # COLMAP's quadratic overlap pairs each image with the ones 1, 2, 4, ... ahead (measured: 24 images, overlap 3
    # and 10 gave 65 and 89 rows), the plain overlap with the next `overlap` ones.
    assert sequential_pairs(24, 3) == 23 + 22 + 20 == 65
    assert sequential_pairs(24, 10) == 23 + 22 + 20 + 16 + 8 == 89
    assert sequential_pairs(24, 3, quadratic=False) == 23 + 22 + 21


def _writer(db_path: Path, rows: int, fail: bool = False):
    """A stand-in for COLMAP's matcher: writes one row per pair into a WAL database, a few milliseconds apart."""
    def match() -> None:
        with sqlite3.connect(db_path) as db:
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("CREATE TABLE matches (pair_id INTEGER PRIMARY KEY)")
        for i in range(rows):
            with sqlite3.connect(db_path) as db:
                db.execute("INSERT INTO matches VALUES (?)", (i,))
            time.sleep(0.03)
        if fail:
            raise RuntimeError("matcher failed")
    return match


@pytest.mark.slow
def test_progress_counts_rows_while_the_matcher_runs(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr("insertnerf_cli.poses.matching.POLL_S", 0.1)
    db_path = tmp_path / "database.db"
    assert pairs_written(db_path) is None  # no database yet
    seen: list[int] = []
    run_with_progress(_writer(db_path, 60), db_path, seen.append)
    assert len(seen) >= 3 and seen == sorted(seen) and 0 <= seen[0] < 60  # counted while rows were written
    assert pairs_written(db_path) == 60


def test_progress_reraises_the_matchers_error(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match="matcher failed"):
        run_with_progress(_writer(tmp_path / "database.db", 3, fail=True), tmp_path / "database.db", lambda n: None)
