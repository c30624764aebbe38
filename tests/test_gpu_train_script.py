"""scripts/gpu_train.py, the driver for a lent GPU machine, run here on the CPU: synthesise, train in the
background, poll and bring the files back, resume a carried run folder, stop with Ctrl-C."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from test_train import tiny_config  # noqa: F401  (fixture)

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "gpu_train.py"


def _script(*args) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True, text=True, env=env,
                          timeout=300)


@pytest.mark.slow
def test_start_poll_bring_back_and_resume_a_carried_run(tmp_path, tiny_config):  # noqa: F811
    data, run, out = tmp_path / "data", tmp_path / "machine" / "run", tmp_path / "OUT"
    train = ["--device", "cpu", "--model-config", tiny_config, "--rays", 16, "--resolution", 16, "--val-every", 2,
             "--ckpt-every", 2, "--log-every", 1]
    synth = ["--synth-arg=--views", "--synth-arg=6", "--synth-arg=--resolution", "--synth-arg=16"]
    started = _script("start", "--data", data, "--scenes", 4, *synth, "--run", run, "--minutes", 5, "--",
                      *train, "--steps", 3)
    assert started.returncode == 0 and "started training" in started.stdout, started.stdout + started.stderr
    polled = _script("poll", "--run", run, "--out", out, "--seconds", 240, "--every", 1)
    assert "the training process has ended" in polled.stdout, polled.stdout + polled.stderr
    assert sorted(p.name for p in out.iterdir()) == ["best.pt", "config.json", "last.pt", "metrics.jsonl",
                                                     "splits.json"]
    assert torch.load(out / "last.pt", weights_only=True)["train"]["step"] == 3

    carried = tmp_path / "next_machine" / "run"  # a carried folder arrives without the pid file and the log
    carried.parent.mkdir()
    subprocess.run(["cp", "-r", str(run), str(carried)], check=True)
    again = _script("start", "--data", data, "--scenes", 4, "--run", carried, "--minutes", 5, "--",
                    *train, "--steps", 5)
    assert "already holds 4 scenes" in again.stdout and "resumed training" in again.stdout, again.stdout
    _script("poll", "--run", carried, "--out", out, "--seconds", 240, "--every", 1)
    steps = [json.loads(line)["step"] for line in (out / "metrics.jsonl").read_text().splitlines()
             if '"train"' in line]
    assert steps[-1] == 5 and torch.load(out / "last.pt", weights_only=True)["train"]["step"] == 5
    assert _script("stop", "--run", carried).returncode != 0  # nothing running: one line, non-zero
