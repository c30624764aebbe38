"""`insertnerf train` on tiny posed scenes the tests make: 2 steps, reload, exact resume, bad input."""
from __future__ import annotations

import json
import math
import os
import signal
import threading
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from click.testing import CliRunner

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.model.checkpoint import load_model, read_checkpoint
from insertnerf_cli.cli.main import cli
from insertnerf_cli.config import ModelConfig, config_to_json
from insertnerf_cli.model import InsertNeRF
from insertnerf_cli.scenes import write_blender_transforms
from insertnerf_cli.training import TrainConfig, train
from cli_fixtures import one_line_error

SIZE = 32  # image side in pixels
RADIUS = 4.0  # camera distance from the sphere at the origin

TINY = ModelConfig(encoder_widths=(4, 4, 4, 4), feature_dims=(4, 4, 4), backbone_decoder_width=4,
                   aggregate_hidden=4, nerf_width=8, nerf_layers=2, appearance_width=8, z_branches=1,
                   film_hidden=8, samples_coarse=8, samples_fine=8, pe_freqs_pos=2, pe_freqs_dir=1, num_views=2)


def orbit_cameras(n: int, phase: float) -> Cameras:
    """n OpenCV cameras on a tilted circle of radius RADIUS, looking at the origin."""
    c2w = []
    for i in range(n):
        a = phase + 2 * math.pi * i / n
        eye = torch.tensor([RADIUS * math.cos(a), RADIUS * math.sin(a), 1.5], dtype=torch.float64)
        forward = -eye / eye.norm()
        right = torch.linalg.cross(forward, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
        right = right / right.norm()
        pose = torch.eye(4, dtype=torch.float64)
        pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, torch.linalg.cross(forward, right), forward, eye
        c2w.append(pose)
    K = intrinsics(SIZE, SIZE, SIZE / 2, SIZE / 2).expand(n, 3, 3).clone()
    return Cameras(K, torch.stack(c2w), SIZE, SIZE)


def sphere_image(cameras: Cameras, i: int, tint: np.ndarray) -> np.ndarray:
    """A unit sphere shaded by its normal and ``tint``, on white: an exact ray cast, uint8 [H, W, 3]."""
    uv = cameras.pixel_grid().reshape(1, -1, 2)
    d = cameras.subset([i]).ray_directions(uv)[0].numpy()  # [P, 3]
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    o = cameras.centers[i].numpy()
    b = d @ o
    disc = b ** 2 - (o @ o - 1.0)
    t = -b - np.sqrt(np.clip(disc, 0.0, None))
    normal = o + t[:, None] * d
    rgb = np.where((disc > 0)[:, None], np.clip(0.5 + 0.5 * normal * tint, 0, 1), 1.0)
    return (rgb.reshape(SIZE, SIZE, 3) * 255).round().astype(np.uint8)


def write_scene(folder: Path, views: int, seed: int) -> None:
    """A Blender-format scene: ``views`` training views and 2 test views of a tinted sphere."""
    rng = np.random.default_rng(seed)
    tint = rng.uniform(0.3, 1.0, size=3)
    for split, n, phase in (("train", views, 0.0), ("test", 2, 0.3)):
        cams = orbit_cameras(n, phase)
        (folder / split).mkdir(parents=True, exist_ok=True)
        names = [f"{split}/r_{i}" for i in range(n)]
        for i, name in enumerate(names):
            iio.imwrite(folder / f"{name}.png", sphere_image(cams, i, tint))
        write_blender_transforms(folder / f"transforms_{split}.json", cams, names, near=2.0, far=6.0,
                                 extra={"layout": "object"})


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("dataset")
    for s in range(3):
        write_scene(root / f"scene_{s}", views=6, seed=s)
    (root / "notes").mkdir()  # not a scene: skipped with a warning
    (root / "manifest.json").write_text("{}")
    return root


@pytest.fixture(scope="module")
def tiny_config(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cfg") / "tiny.json"
    path.write_text(json.dumps(config_to_json(TINY)))
    return path


def small(**changes) -> TrainConfig:
    base = dict(model=TINY, steps=4, rays=32, resolution=SIZE, val_every=2, val_rays=64, ckpt_every=2, log_every=1,
                val_scenes=1)
    base.update(changes)
    return TrainConfig(**base)


def cli_args(dataset: Path, out: Path, tiny_config: Path, *extra: str) -> list[str]:
    return ["train", str(dataset), "--out", str(out), "--device", "cpu", "--model-config", str(tiny_config),
            "--rays", "32", "--resolution", str(SIZE), "--val-every", "1000", "--ckpt-every", "1", "--log-every", "1", *extra]


@pytest.mark.slow
def test_cli_trains_two_steps_then_the_checkpoint_reloads_and_resumes(dataset, tiny_config, tmp_path):
    out = tmp_path / "run"
    result = CliRunner().invoke(cli, cli_args(dataset, out, tiny_config, "--steps", "2"))
    assert result.exit_code == 0, result.output
    assert "skipping notes" in result.output
    payload = torch.load(out / "checkpoints" / "last.pt", weights_only=True)  # tensors and plain types only
    assert payload["train"]["step"] == 2
    model, config = load_model(out / "checkpoints" / "last.pt", torch.device("cpu"))
    assert config == TINY and not model.training
    lines = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    train_lines = [m for m in lines if m["split"] == "train"]
    assert [m["step"] for m in train_lines] == [1, 2]
    assert all(math.isfinite(m["total"]) and m["rays_per_s"] > 0 and m["lr"] > 0 for m in train_lines)
    assert any(m["split"] == "val" and math.isfinite(m["psnr"]) for m in lines)
    splits = json.loads((out / "splits.json").read_text())
    assert len(splits["val"]) == 1 and len(splits["train"]) == 2
    assert (out / "checkpoints" / "config.json").is_file() and (out / "checkpoints" / "best.pt").is_file()

    again = CliRunner().invoke(cli, cli_args(dataset, out, tiny_config, "--steps", "3", "--resume"))
    assert again.exit_code == 0, again.output
    assert read_checkpoint(out / "checkpoints" / "last.pt").train_state.step == 3
    steps = [json.loads(line)["step"] for line in (out / "metrics.jsonl").read_text().splitlines()
             if json.loads(line)["split"] == "train"]
    assert steps == [1, 2, 3]


@pytest.mark.slow
def test_resumed_training_matches_uninterrupted_training_exactly(dataset, tmp_path):
    cpu = torch.device("cpu")
    straight = train(dataset, tmp_path / "straight", small(steps=4), cpu)
    train(dataset, tmp_path / "split", small(steps=2), cpu)
    resumed = train(dataset, tmp_path / "split", small(steps=4), cpu, resume=True)
    assert straight.step == resumed.step == 4 and resumed.steps_this_session == 2
    a = read_checkpoint(straight.checkpoint)
    b = read_checkpoint(resumed.checkpoint)
    assert a.model_state.keys() == b.model_state.keys()
    for name in a.model_state:
        assert torch.equal(a.model_state[name], b.model_state[name]), name
    for key in ("torch", "data", "python", "numpy_keys"):
        assert torch.equal(a.train_state.rng[key], b.train_state.rng[key]), key
    # ... and the steps did move the weights away from the seeded initialisation.
    torch.manual_seed(small().seed)
    initial = InsertNeRF(TINY).state_dict()
    assert any(not torch.equal(initial[n], a.model_state[n]) for n in initial)


@pytest.mark.slow
def test_diverging_loss_stops_with_one_line_and_keeps_the_checkpoint(dataset, tiny_config, tmp_path):
    out = tmp_path / "run"
    result = CliRunner().invoke(cli, cli_args(dataset, out, tiny_config, "--steps", "6", "--lr", "1e30"))
    message = one_line_error(result)
    assert "diverged" in message
    kept = read_checkpoint(out / "checkpoints" / "last.pt")  # written at step 1, still loadable
    assert kept.train_state.step >= 1
    assert all(torch.isfinite(t).all() for t in kept.model_state.values() if t.is_floating_point())


def test_empty_or_unreadable_dataset_is_one_line(tmp_path, tiny_config):
    data = tmp_path / "data"
    (data / "junk").mkdir(parents=True)
    (data / "junk" / "readme.txt").write_text("not a scene")
    result = CliRunner().invoke(cli, cli_args(data, tmp_path / "run", tiny_config, "--steps", "1"))
    assert "no readable scene" in one_line_error(result)
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_scene_with_too_few_views_is_one_line(tmp_path, tiny_config):
    write_scene(tmp_path / "data" / "thin", views=2, seed=0)
    result = CliRunner().invoke(cli, cli_args(tmp_path / "data", tmp_path / "run", tiny_config, "--views", "4"))
    assert "lower --views" in one_line_error(result)


@pytest.mark.slow
def test_run_folder_rules(dataset, tiny_config, tmp_path):
    out = tmp_path / "run"
    assert CliRunner().invoke(cli, cli_args(dataset, out, tiny_config, "--steps", "1")).exit_code == 0
    before = (out / "checkpoints" / "last.pt").read_bytes()
    assert "--resume" in one_line_error(CliRunner().invoke(cli, cli_args(dataset, out, tiny_config, "--steps", "1")))
    assert "contradict" in one_line_error(CliRunner().invoke(
        cli, cli_args(dataset, out, tiny_config, "--resume", "--overwrite")))
    changed = one_line_error(CliRunner().invoke(
        cli, cli_args(dataset, out, tiny_config, "--resume", "--steps", "2", "--conditioning", "concat")))
    assert "another model config" in changed
    assert (out / "checkpoints" / "last.pt").read_bytes() == before  # refused runs touched nothing
    assert "nothing to resume" in one_line_error(CliRunner().invoke(
        cli, cli_args(dataset, tmp_path / "fresh", tiny_config, "--resume")))
    redo = CliRunner().invoke(cli, cli_args(dataset, out, tiny_config, "--steps", "1", "--overwrite",
                                            "--conditioning", "concat"))
    assert redo.exit_code == 0, redo.output
    assert read_checkpoint(out / "checkpoints" / "last.pt").model_config.conditioning == "concat"


@pytest.mark.slow
def test_ctrl_c_saves_a_checkpoint_and_resume_continues(dataset, tmp_path):
    out = tmp_path / "run"
    config = small(steps=100_000, val_every=100_000, ckpt_every=100_000)

    def interrupt_once_training_runs() -> None:
        deadline = time.monotonic() + 60
        while not (out / "metrics.jsonl").exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=interrupt_once_training_runs, daemon=True).start()
    result = train(dataset, out, config, torch.device("cpu"))
    assert result.stopped == "interrupted" and 1 <= result.step < 100_000
    assert read_checkpoint(out / "checkpoints" / "last.pt").train_state.step == result.step
    more = train(dataset, out, small(steps=result.step + 1), torch.device("cpu"), resume=True)
    assert more.step == result.step + 1 and more.stopped == "steps"


@pytest.mark.slow
def test_time_budget_stops_and_saves(dataset, tmp_path):
    result = train(dataset, tmp_path / "run", small(steps=100_000, minutes=0.02), torch.device("cpu"))
    assert result.stopped == "minutes" and result.step >= 1
    assert result.elapsed_s >= 0.02 * 60
    assert read_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt").train_state.step == result.step
