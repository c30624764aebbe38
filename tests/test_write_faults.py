"""Faults while writing: a full disk (a real, small tmpfs) during render and train, and frames a power loss left
zero-byte or truncated under their final names."""
from __future__ import annotations

import errno
import os
import subprocess
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from click.testing import CliRunner
from test_output_safety import snapshot, trained_run
from cli_fixtures import make_checkpoint, make_scene, one_line_error, render_command
from test_train import cli_args, tiny_config  # noqa: F401  (tiny_config is a fixture)

from insertnerf_cli.files.atomic import WriteError, write_bytes
from insertnerf_cli.model.checkpoint import read_checkpoint
from insertnerf_cli.cli.main import cli

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture
def small_disk(tmp_path):
    """A 2 MiB tmpfs at tmp_path/disk (needs root: mount); unmounted afterwards."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(disk)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({mounted.stderr.decode().strip()[:80]}): needs root")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def fill(disk: Path, leave_bytes: int = 0) -> Path:
    """Fill ``disk`` until at most ``leave_bytes`` are free; returns the filler file (delete it to free space)."""
    filler = disk / "filler.bin"
    with open(filler, "wb") as handle:
        while True:
            free = _free(disk)
            if free <= leave_bytes:
                break
            try:
                handle.write(b"\0" * min(free - leave_bytes, 1 << 16))
                handle.flush()
            except OSError as err:
                assert err.errno == errno.ENOSPC
                break
    return filler


def _free(disk: Path) -> int:
    st = os.statvfs(disk)
    return st.f_bavail * st.f_frsize


def no_temporaries(folder: Path) -> bool:
    return not [p for p in folder.rglob("*") if ".tmp" in p.name]


def test_disk_full_write_is_one_error_and_keeps_the_old_file(small_disk):
    target = small_disk / "a.bin"
    write_bytes(target, b"old")
    fill(small_disk)
    with pytest.raises(WriteError, match="disk full at .*a.bin: free space and re-run"):
        write_bytes(target, b"x" * 100_000)
    assert target.read_bytes() == b"old" and no_temporaries(small_disk)


@pytest.mark.slow
def test_render_on_a_full_disk_keeps_finished_frames_and_resumes(small_disk, tmp_path):
    scene, ckpt = make_scene(tmp_path / "scene", {"train": 6}), make_checkpoint(tmp_path / "tiny.pt")
    out = small_disk / "views"
    assert render_command(scene, ckpt, out, "--frames", 3).exit_code == 0
    for sub in ("frames", "depth", "depth_vis"):  # as if the run had stopped before frame 2
        (out / sub / "00002.png").unlink()
    (out / "video.mp4").unlink()
    kept = snapshot(out / "frames")
    filler = fill(small_disk)
    message = one_line_error(render_command(scene, ckpt, out, "--frames", 3), "disk full at", "free space and re-run")
    assert "00002.png" in message
    assert snapshot(out / "frames") == kept and no_temporaries(out)
    filler.unlink()
    again = render_command(scene, ckpt, out, "--frames", 3)
    assert again.exit_code == 0 and "rendered 1 (2 kept" in again.output, again.output


@pytest.mark.slow
def test_train_on_a_full_disk_keeps_the_last_checkpoint(small_disk, tiny_config, tmp_path):
    data, out = trained_run(tmp_path, small_disk / "run", tiny_config)
    last = out / "checkpoints" / "last.pt"
    before = last.read_bytes()
    # Room for the small files, not for a second copy of the checkpoint (written beside the old one).
    fill(small_disk, leave_bytes=len(before) // 2)
    result = CliRunner().invoke(cli, cli_args(data, out, tiny_config, "--steps", "2", "--resume"))
    message = one_line_error(result, "disk full while saving", "last.pt", "step 1 is kept")
    assert "at step 2; training stopped" in message and len(message) < 300, message
    assert last.read_bytes() == before and read_checkpoint(last).train_state.step == 1
    assert no_temporaries(out)


@pytest.mark.slow
def test_zero_byte_and_truncated_frames_are_rendered_again(tmp_path):
    scene, ckpt = make_scene(tmp_path / "scene", {"train": 6}), make_checkpoint(tmp_path / "tiny.pt")
    out = tmp_path / "views"
    assert render_command(scene, ckpt, out, "--frames", 3).exit_code == 0
    good = (out / "frames" / "00000.png").stat().st_mtime_ns
    (out / "frames" / "00001.png").write_bytes(b"")  # a power loss after the rename, before the data
    depth = out / "depth" / "00002.png"
    depth.write_bytes(depth.read_bytes()[: len(depth.read_bytes()) // 2])
    result = render_command(scene, ckpt, out, "--frames", 3)
    assert result.exit_code == 0, result.output
    assert "rendered 2 (1 kept" in result.output
    assert (out / "frames" / "00000.png").stat().st_mtime_ns == good
    assert iio.imread(out / "frames" / "00001.png").shape[:2] == iio.imread(depth).shape


@pytest.mark.slow
def test_failed_render_of_photos_leaves_no_output_behind(tmp_path):
    """Posing 3 noise photos fails; the output folder this run created is gone again (no render_config.json)."""
    photos = tmp_path / "photos"
    photos.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        iio.imwrite(photos / f"{i}.png", rng.integers(0, 255, (64, 64, 3), dtype=np.uint8))
    ckpt = make_checkpoint(tmp_path / "tiny.pt")
    result = render_command(photos, ckpt, tmp_path / "views", "--frames", 1)
    assert result.exit_code == 1 and "Traceback" not in result.output, result.output
    assert not (tmp_path / "views").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos", "tiny.pt"]
