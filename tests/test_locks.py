"""One writer per output (lock.py) and the bundled weights as inputs (issue 29).

The race is real: two `insertnerf render` processes on one tiny scene and one output folder. The first is frozen
(SIGSTOP) once it holds the lock, so the second always meets it, whatever the machine's speed.
"""
from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import pytest
from click.testing import CliRunner

from insertnerf_cli.cli.main import cli
from insertnerf_cli.files.lock import LOCK_NAME, OutputLocked, lock_file, lock_output, releases_output_locks
from insertnerf_cli.files.outdir import BUNDLED_WEIGHTS_DIR, OutputRecord, foreign_entries, holds_files
from cli_fixtures import make_checkpoint, make_scene

ROOT = Path(__file__).resolve().parents[1]
MAIN = "import sys; sys.argv[0] = 'insertnerf'; from insertnerf_cli.cli.main import main; main()"
HOLD = ("import sys, time; from insertnerf_cli.files.lock import lock_output; lock_output(sys.argv[1], 'render'); "
        "print('held', flush=True); time.sleep(120)")


def _env() -> dict[str, str]:
    return dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))


def _holder(folder: Path) -> subprocess.Popen:
    """Another process that takes the lock of ``folder`` and keeps it."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], env=_env(), stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_second_writer_is_refused_naming_the_holder_and_a_killed_holder_leaves_no_lock(tmp_path: Path) -> None:
    out = tmp_path / "out"
    holder = _holder(out)
    try:
        with pytest.raises(OutputLocked, match=rf"another insertnerf render \(pid {holder.pid}\)"):
            releases_output_locks(lock_output)(out, "eval")
    finally:
        holder.kill()  # SIGKILL: no clean-up runs, the kernel drops the flock
        holder.wait()
    assert (out / LOCK_NAME).is_file()  # the file stays, but it is no longer a lock
    assert not holds_files(out) and foreign_entries(out, "render") == []
    releases_output_locks(lock_output)(out, "render")  # the next run takes it at once
    assert not (out / LOCK_NAME).exists()


def test_lock_is_released_when_the_command_returns_and_its_folder_goes_if_nothing_was_written(
        tmp_path: Path) -> None:
    out = tmp_path / "new" / "out"

    @releases_output_locks
    def writer(write: bool) -> None:
        lock_output(out, "render")
        lock_output(out, "render")  # re-entrant in one process
        assert (out / LOCK_NAME).read_text().split() == [str(os.getpid()), "render"]
        if write:
            OutputRecord(out, "render").claim("a.txt")
            (out / "a.txt").write_text("x")

    writer(write=False)
    assert not (tmp_path / "new").exists()  # created for the lock only: removed again
    writer(write=True)
    assert sorted(p.name for p in out.iterdir()) == [".insertnerf-outputs.json", "a.txt"]


def test_file_output_lock_lies_beside_the_file(tmp_path: Path) -> None:
    assert lock_file(tmp_path / "ft.pt", is_dir=False) == tmp_path / ".ft.pt.insertnerf-lock"
    holder = subprocess.Popen([sys.executable, "-c", HOLD.replace("lock_output(sys.argv[1], 'render')",
                                                                  "lock_output(sys.argv[1], 'finetune', False)"),
                               str(tmp_path / "ft.pt")], env=_env(), stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(OutputLocked, match=r"finetune \(pid"):
            releases_output_locks(lock_output)(tmp_path / "ft.pt", "finetune", False)
    finally:
        holder.kill()
        holder.wait()


def _pid_written(path: Path) -> bool:
    try:
        return bool(path.read_text().strip())
    except OSError:
        return False


def _render_args(scene: Path, out: Path, ckpt: Path, *extra: str) -> list[str]:
    return [sys.executable, "-c", MAIN, "render", str(scene), "--out", str(out), "--checkpoint", str(ckpt),
            "--device", "cpu", *extra]


@pytest.mark.slow
def test_two_renders_race_on_one_folder_the_second_is_refused_and_the_first_finishes_whole(tmp_path: Path) -> None:
    scene, ckpt = make_scene(tmp_path / "scene", {"train": 6}), make_checkpoint(tmp_path / "tiny.pt")
    out = tmp_path / "out"
    first = subprocess.Popen(_render_args(scene, out, ckpt, "--frames", "3", "--resolution", "32"), env=_env(),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not _pid_written(out / LOCK_NAME) and first.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        first.send_signal(signal.SIGSTOP)  # frozen while it holds the lock
        assert (out / LOCK_NAME).is_file(), first.communicate()
        second = subprocess.run(_render_args(scene, out, ckpt, "--frames", "2", "--resolution", "16", "--overwrite"),
                                env=_env(), capture_output=True, text=True, timeout=300)
        first.send_signal(signal.SIGCONT)
        out_1, err_1 = first.communicate(timeout=300)
    finally:
        first.kill()
    assert second.returncode == 1, second.stderr
    lines = [line for line in (second.stdout + second.stderr).splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in second.stderr
    assert f"is being written by another insertnerf render (pid {first.pid})" in lines[0], lines[0]
    assert first.returncode == 0, err_1
    cameras = json.loads((out / "cameras.json").read_text())
    frames = sorted(p.name for p in (out / "frames").iterdir())
    assert len(cameras["frames"]) == 3 and len(frames) == 3
    assert {cv2.imread(str(out / "frames" / f)).shape for f in frames} == {(24, 32, 3)}
    assert not (out / LOCK_NAME).exists()


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("command", ["finetune", "render", "train", "eval"])
def test_no_command_writes_under_the_bundled_weights(tmp_path: Path, command: str) -> None:
    scene = make_scene(tmp_path / "scene", {"train": 4})
    bundled = sorted(BUNDLED_WEIGHTS_DIR.glob("*.pt"))
    before = {p.name: _sha(p) for p in bundled}
    target = {"finetune": BUNDLED_WEIGHTS_DIR / "insertnerf.pt", "render": BUNDLED_WEIGHTS_DIR,
              "train": BUNDLED_WEIGHTS_DIR / "run", "eval": BUNDLED_WEIGHTS_DIR / "side"}[command]
    args = {"finetune": ["finetune", str(scene), "--out", str(target), "--overwrite", "--steps", "1"],
            "render": ["render", str(scene), "--out", str(target), "--overwrite"],
            "train": ["train", str(scene), "--out", str(target)],
            "eval": ["eval", str(scene), "--out", str(target), "--overwrite"]}[command]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 1 and isinstance(result.exception, SystemExit), result.output
    assert "bundled weights folder" in result.output and len(result.output.strip().splitlines()) == 1
    assert {p.name: _sha(p) for p in sorted(BUNDLED_WEIGHTS_DIR.glob("*.pt"))} == before
    assert sorted(p.name for p in BUNDLED_WEIGHTS_DIR.iterdir()) == [p.name for p in bundled]
