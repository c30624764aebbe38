"""A render's frames and an eval's views in several processes (pipelines/processes.py): the same files and scores
as one process, children that fail leave their items to the parent, and Ctrl-C stops every process at once."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from cli_fixtures import make_checkpoint, make_scene, render_command, run
from test_interrupts import LIMIT_S, MAIN, _ctrl_c_as_in_a_terminal

from insertnerf_cli.exporters.outputs import depth_scale_for
from insertnerf_cli.pipelines.frames import FrameWriter
from insertnerf_cli.pipelines.processes import MAX_WORKERS, RendererSpec, run_side_by_side, worker_count
from insertnerf_cli.rendering.camera_paths import make_path
from insertnerf_cli.rendering.options import RenderOptions
from insertnerf_cli.rendering.view_renderer import ViewRenderer, load_model
from insertnerf_cli.scenes import load_scene, normalize_scene

pytestmark = pytest.mark.usefixtures("one_thread")  # one thread here, as in every frame process: the same bits


def test_worker_count(monkeypatch):
    assert worker_count(3, 2, "cpu") == 2  # never more processes than frames
    assert worker_count(None, 30, "cuda") == 1
    monkeypatch.setattr(torch, "get_num_threads", lambda: 2)
    assert worker_count(None, 30, "cpu") == 2
    assert worker_count(None, 5, "cpu") == 1  # a child's start-up would cost more than its frames save
    monkeypatch.setattr(torch, "get_num_threads", lambda: 64)
    assert worker_count(None, 300, "cpu") == MAX_WORKERS
    assert worker_count(None, 12, "cpu") == 4


def _frames(folder: Path) -> dict[str, np.ndarray]:
    return {f"{sub}/{f.name}": iio.imread(f) for sub in ("frames", "depth", "depth_vis")
            for f in sorted((folder / sub).iterdir())}


def test_render_with_two_processes_writes_the_files_of_one(tmp_path):
    scene = make_scene(tmp_path / "scene", {"train": 8})
    ckpt = make_checkpoint(tmp_path / "tiny.pt")
    one = render_command(scene, ckpt, tmp_path / "one", "--frames", 6, "--workers", 1)
    two = render_command(scene, ckpt, tmp_path / "two", "--frames", 6, "--workers", 2)
    assert one.exit_code == 0 and two.exit_code == 0, (one.output, two.output)
    first, second = _frames(tmp_path / "one"), _frames(tmp_path / "two")
    assert len(first) == 18 and first.keys() == second.keys()
    assert all(np.array_equal(first[k], second[k]) for k in first)


class _SlowRenderer(ViewRenderer):
    """This process's renderer, slowed so that the spawned child (a few seconds to start) gets frames to render."""

    def render(self, *args, **kwargs):
        time.sleep(2.0)
        return super().render(*args, **kwargs)


def _job(tmp_path: Path, checkpoint: Path, frames: int):
    scene, _ = normalize_scene(load_scene(make_scene(tmp_path / "scene", {"train": 8})))
    size = (12, 16)
    path = make_path("orbit", scene.cameras, scene.near, scene.far, frames, size)
    spec = RendererSpec(checkpoint, scene, size, 2, "cpu", None, False, False, RenderOptions())
    writer = FrameWriter(path, tmp_path / "out", 1.0, depth_scale_for(float(path.far.max())), "png16")
    return spec, path, writer


def test_a_child_renders_from_the_back_and_a_failed_child_leaves_its_frames_to_the_parent(tmp_path):
    ckpt = make_checkpoint(tmp_path / "tiny.pt")
    spec, path, writer = _job(tmp_path, ckpt, 6)
    parent = _SlowRenderer(load_model(ckpt, "cpu"), spec.scene, spec.size, 2, sfm_depth=False)
    done = list(run_side_by_side(parent, spec, writer, list(range(6)), workers=2))
    assert sorted(i for i, _, _ in done) == list(range(6))
    by_child = sorted(i for i, _, who in done if who == 1)
    assert by_child and by_child == list(range(6 - len(by_child), 6))  # taken from the back
    alone = replace(writer, out_dir=tmp_path / "alone")
    assert len(list(run_side_by_side(spec.build(), spec, alone, list(range(6)), workers=1))) == 6
    first, second = _frames(writer.out_dir), _frames(alone.out_dir)
    assert len(first) == 18 and first.keys() == second.keys()
    assert all(np.array_equal(first[k], second[k]) for k in first)  # the child's frames too

    broken = replace(spec, checkpoint=tmp_path / "missing.pt")  # the child cannot load its weights
    writer = replace(writer, out_dir=tmp_path / "broken")
    done = list(run_side_by_side(spec.build(), broken, writer, list(range(4)), workers=2))
    assert sorted(i for i, _, _ in done) == list(range(4)) and all(who == 0 for _, _, who in done)


def _frame_children(pid: int) -> list[int]:
    """Process ids of the frame processes that ``pid`` spawned (multiprocessing's spawn_main, not its resource
    tracker)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parent = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
                command = (entry / "cmdline").read_bytes()
            except (OSError, IndexError, ValueError):
                continue
            if parent == pid and b"spawn_main" in command:
                found.append(int(entry.name))
    return found


def _running(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        return (Path(f"/proc/{pid}") / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="lists processes through /proc")
def test_ctrl_c_while_two_processes_render_exits_130_at_once_and_leaves_no_process(tmp_path):
    scene = make_scene(tmp_path / "scene", {"train": 8})
    ckpt = make_checkpoint(tmp_path / "tiny.pt")
    out = tmp_path / "views"
    args = ["render", str(scene), "--out", str(out), "--checkpoint", str(ckpt), "--device", "cpu", "--frames", "400",
            "--resolution", "64", "--views", "2", "--workers", "2"]
    proc = subprocess.Popen([sys.executable, "-c", MAIN, *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"}, preexec_fn=_ctrl_c_as_in_a_terminal)
    seen = b""
    while b"2 processes" not in seen:
        data = os.read(proc.stderr.fileno(), 4096)
        assert data, seen.decode(errors="replace")
        seen += data
    deadline = time.monotonic() + 30
    while not any(f.suffix == ".png" for f in (out / "frames").glob("*")) or not _frame_children(proc.pid):
        assert time.monotonic() < deadline, "no frame and no child within 30 s"
        time.sleep(0.2)
    time.sleep(1.0)  # both processes rendering
    children = _frame_children(proc.pid)
    sent = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    code = proc.wait(timeout=30)
    took = time.perf_counter() - sent
    err = (seen + proc.stderr.read()).decode(errors="replace")
    assert code == 130 and took < LIMIT_S, (code, took, err[-500:])
    assert "Traceback" not in err
    assert children and not [pid for pid in children if _running(pid)]


def test_eval_with_two_processes_scores_as_one(tmp_path):
    scene = make_scene(tmp_path / "scene", {"train": 8, "test": 6})
    ckpt = make_checkpoint(tmp_path / "tiny.pt")
    reports = []
    for workers in (1, 2):
        json_path = tmp_path / f"eval{workers}.json"
        result = run("eval", scene, "--checkpoint", ckpt, "--device", "cpu", "--resolution", 16, "--views", "2,3",
                     "--workers", workers, "--json", json_path)
        assert result.exit_code == 0, result.output
        reports.append(json.loads(json_path.read_text()))
    def scores(report: dict) -> list:  # every field but the time each render took
        return [[{k: v for k, v in view.items() if k != "seconds"} for view in r["views"]] for r in report["by_count"]]

    assert scores(reports[0]) == scores(reports[1])
    assert len(scores(reports[0])[0]) == 6 and "psnr" in scores(reports[0])[0][0]
