"""Atomic writes: all or nothing under the final name, with ordinary file permissions."""
import os
import subprocess
import sys

import pytest

from insertnerf_cli.files.atomic import atomic_path, write_json


def test_a_failed_write_leaves_neither_the_file_nor_a_temporary(tmp_path):
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "out.png") as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []


def test_written_files_get_the_permissions_of_a_plain_open(tmp_path):
    write_json(tmp_path / "a.json", {"x": 1})
    with open(tmp_path / "b.json", "w") as f:
        f.write("{}")
    assert os.stat(tmp_path / "a.json").st_mode == os.stat(tmp_path / "b.json").st_mode


def test_a_killed_writers_temporary_is_removed_by_the_next_write_of_that_file(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stray = tmp_path / f".last.{dead.pid}-abc.tmp.pt"  # what kill -9 during save_checkpoint leaves
    live = tmp_path / f".last.{os.getpid()}-def.tmp.pt"  # a writer that is still running
    stray.write_bytes(b"half")
    live.write_bytes(b"busy")
    with atomic_path(tmp_path / "last.pt") as tmp:
        tmp.write_bytes(b"whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == [live.name, "last.pt"]
