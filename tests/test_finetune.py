"""`insertnerf finetune` and `render --finetune`: held-out views never drawn, checkpoints that render/eval load,
Ctrl-C saves, and --out safety (tiny Blender scenes and a tiny random-init base checkpoint)."""
from __future__ import annotations

import os
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_fixtures import make_checkpoint, make_scene, run

from insertnerf_cli.finetune import FinetuneConfig, Progress, finetune
from insertnerf_cli.finetune import loop as finetune_loop
from insertnerf_cli.model.checkpoint import load_model
from insertnerf_cli.finetune.data import FrozenFeatures, draw, finetune_scene
from insertnerf_cli.training.data import ImageCache, decode_uint8
from insertnerf_cli.scenes import load_scene, normalize_scene
from insertnerf_cli.scenes.views import held_out_views

pytestmark = pytest.mark.usefixtures("one_thread")
REPO = Path(__file__).resolve().parents[1]
TINY_RUN = ("--device", "cpu", "--resolution", 16, "--views", 3, "--rays", 16)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return make_checkpoint(tmp_path_factory.mktemp("finetune") / "base.pt")


def _finetune(scene, base, out, *extra):
    return run("finetune", scene, "--out", out, "--checkpoint", base, *TINY_RUN, *extra)


@pytest.mark.slow
@pytest.mark.parametrize("splits, held", [({"train": 10}, [0, 8]), ({"train": 6, "test": 2}, [6, 7])])
def test_held_out_views_never_reach_the_draws(tmp_path, splits, held):
    # {"train": 10}: the scene's own train split holds every view, so eval's every-8th rule must be applied here.
    scene_dir = make_scene(tmp_path / "scene", splits)
    assert held_out_views(normalize_scene(load_scene(scene_dir))[0]) == held
    scene = finetune_scene(scene_dir, 16)
    assert scene.test_ids == tuple(held) and not set(scene.train_ids) & set(held)
    rng = np.random.default_rng(0)
    targets, sources = set(), set()
    for _ in range(2000):
        d = draw(rng, scene, 3, 4)
        targets.add(d.target)
        sources.update(d.sources)
    usable = set(range(sum(splits.values()))) - set(held)
    assert targets == usable and sources == usable  # every usable view is drawn, no held-out one ever


@pytest.mark.slow
def test_the_real_loop_draws_only_usable_views(tmp_path, base, monkeypatch):
    scene_dir = make_scene(tmp_path / "scene", {"train": 10})
    seen: list[tuple[int, ...]] = []

    def recording_draw(*args, **kwargs):  # the real draw, its result recorded
        d = draw(*args, **kwargs)
        seen.append((d.target, *d.sources))
        return d

    monkeypatch.setattr(finetune_loop, "draw", recording_draw)
    config = FinetuneConfig(minutes=None, steps=5, rays=16, views=3, resolution=16)
    result = finetune(scene_dir, tmp_path / "ft.pt", config, torch.device("cpu"), base=base)
    assert result.steps == 5 and len(seen) == 5 and (result.usable_views, result.held_out_views) == (8, 2)
    assert not {i for draw_ids in seen for i in draw_ids} & {0, 8}


def test_sources_colours_can_come_from_the_photos_at_twice_the_size(tmp_path, base):
    scene = finetune_scene(make_scene(tmp_path / "scene", {"train": 10}), 16)  # photos larger than 16 px
    model = load_model(base, torch.device("cpu"))[0]
    h, w = scene.cameras.height, scene.cameras.width
    frozen = FrozenFeatures(model, scene, ImageCache(1 << 20), colour_scale=2.0)
    picked = frozen.select((5, 1))
    torch.testing.assert_close(picked.colours, scene.scene.load_sizes([5, 1], [(2 * h, 2 * w)])[0].permute(0, 3, 1, 2))
    assert (picked.height, picked.width) == (h, w)
    assert FrozenFeatures(model, scene, ImageCache(1 << 20), colour_scale=1.0).select((5, 1)).colours is None


def test_finer_colours_decode_each_photo_once_and_fill_the_cache(tmp_path, base, monkeypatch):
    scene = finetune_scene(make_scene(tmp_path / "scene", {"train": 10}), 16)
    model = load_model(base, torch.device("cpu"))[0]
    decoded: list[int] = []
    real = type(scene.scene)._decoded

    def counting(self, index):
        decoded.append(index)
        return real(self, index)

    monkeypatch.setattr(type(scene.scene), "_decoded", counting)
    cache = ImageCache(1 << 20)
    FrozenFeatures(model, scene, cache, colour_scale=2.0)
    assert sorted(decoded) == sorted(scene.train_ids)  # the training size and the finer one from one decode
    cached = [cache.get(scene, i) for i in scene.train_ids]
    assert len(decoded) == len(scene.train_ids)  # later steps find every source in the cache
    for i, image in zip(scene.train_ids, cached):  # and it holds what the cache would have decoded itself
        torch.testing.assert_close(image, decode_uint8(scene, i), rtol=0, atol=0)


@pytest.mark.slow
def test_two_step_finetune_writes_weights_that_render_and_eval_load(tmp_path, base):
    scene = make_scene(tmp_path / "scene", {"train": 6, "test": 2})
    out = tmp_path / "ft.pt"
    result = _finetune(scene, base, out, "--steps", 2)
    assert result.exit_code == 0, result.output
    assert "steps: 2 steps" in result.output and "2 held out for eval, never used" in result.output
    payload = torch.load(out, map_location="cpu", weights_only=True)
    before = torch.load(base, map_location="cpu", weights_only=True)
    assert payload["model_config"] == before["model_config"]
    changed = [n for n, t in payload["model"].items() if not torch.equal(t, before["model"][n])]
    assert changed and not any(n.startswith("encoder.") for n in changed)  # the encoder is frozen by default
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]
    rendered = run("render", scene, "--out", tmp_path / "video", "--checkpoint", out, "--device", "cpu",
                   "--resolution", 16, "--views", 3, "--frames", 2)
    assert rendered.exit_code == 0, rendered.output
    scored = run("eval", scene, "--checkpoint", out, "--device", "cpu", "--resolution", 16, "--views", 3)
    assert scored.exit_code == 0 and "mean over 2 held-out views" in scored.output, scored.output


@pytest.mark.slow
def test_backbone_nerfpp_finetunes_the_bundled_nerfpp_generator(tmp_path):
    scene = make_scene(tmp_path / "scene", {"train": 6, "test": 2})
    out = tmp_path / "ft.pt"
    result = run("finetune", scene, "--out", out, "--backbone", "nerfpp", *TINY_RUN, "--steps", 1)
    assert result.exit_code == 0, result.output
    assert load_model(out, torch.device("cpu"))[1].backbone == "nerfpp"


@pytest.mark.slow
def test_train_encoder_changes_the_encoder_too(tmp_path, base):
    scene = make_scene(tmp_path / "scene", {"train": 6})
    assert _finetune(scene, base, tmp_path / "ft.pt", "--steps", 2, "--train-encoder").exit_code == 0
    after = torch.load(tmp_path / "ft.pt", weights_only=True)["model"]
    before = torch.load(base, weights_only=True)["model"]
    assert any(not torch.equal(after[n], before[n]) for n in after if n.startswith("encoder."))


@pytest.mark.slow
def test_ctrl_c_finishes_the_step_and_saves(tmp_path, base):
    scene = make_scene(tmp_path / "scene", {"train": 6})
    steps_seen = []

    def press_ctrl_c(progress: Progress) -> None:
        steps_seen.append(progress.step)
        if progress.step == 2:
            os.kill(os.getpid(), signal.SIGINT)  # a real signal through the installed handler

    config = FinetuneConfig(minutes=None, steps=1000, rays=16, views=3, resolution=16)
    # A process started in the background by a shell ignores SIGINT; the handler must go back to what it was.
    before = signal.getsignal(signal.SIGINT)
    result = finetune(scene, tmp_path / "ft.pt", config, torch.device("cpu"), base=base, on_step=press_ctrl_c,
                      say=lambda _: None)
    assert result.stopped == "interrupted" and result.steps == 2 and steps_seen == [1, 2]
    assert torch.load(tmp_path / "ft.pt", weights_only=True)["format"] == "insertnerf-checkpoint"
    assert signal.getsignal(signal.SIGINT) is before  # the handler was put back


@pytest.mark.slow
def test_ctrl_c_on_the_command_exits_130_with_the_saved_file(tmp_path, base):
    scene = make_scene(tmp_path / "scene", {"train": 6})
    out = tmp_path / "ft.pt"
    args = ["finetune", scene, "--out", out, "--checkpoint", base, *TINY_RUN, "--steps", 100000]
    proc = subprocess.Popen([sys.executable, "-c", "from insertnerf_cli.cli.main import main; main()", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"})
    try:
        _wait_for_a_finished_step(proc)
    except BaseException:
        proc.kill()
        raise
    proc.send_signal(signal.SIGINT)
    out_text, err_text = proc.communicate(timeout=60)
    assert proc.returncode == 130, err_text[-500:]
    assert out.is_file() and "interrupted:" in out_text and f"--checkpoint {out}" in out_text


def _wait_for_a_finished_step(proc: subprocess.Popen, limit_s: float = 120.0) -> None:
    """Read the child's progress bar until it shows at least one step done (so its Ctrl-C handler is installed and
    there is something to save). tqdm redraws at most every 0.1 s, so any count >= 1 is accepted, not one value."""
    progress, deadline = "", time.monotonic() + limit_s
    while not re.search(r"\b[1-9]\d*/100000\b", progress):
        assert time.monotonic() < deadline, f"no finished step within {limit_s:.0f} s: {progress[-500:]}"
        if select.select([proc.stderr], [], [], 1.0)[0]:  # raw reads: the text wrapper's buffer is never filled
            chunk = os.read(proc.stderr.fileno(), 4096).decode(errors="replace")
            assert chunk, f"finetune ended early: {progress[-500:]}"
            progress += chunk


@pytest.mark.slow
def test_out_is_refused_when_it_exists_or_lies_in_the_scene(tmp_path, base):
    scene = make_scene(tmp_path / "scene", {"train": 6})
    existing = tmp_path / "ft.pt"
    existing.write_bytes(b"mine")
    refused = _finetune(scene, base, existing, "--steps", 1)
    assert refused.exit_code == 1 and "--overwrite" in refused.output and existing.read_bytes() == b"mine"
    inside = scene / "ft.pt"
    refused = _finetune(scene, base, inside, "--steps", 1)
    assert refused.exit_code == 1 and "lies inside the input scene" in refused.output and not inside.exists()
    assert "Traceback" not in refused.output
    before = Path(base).read_bytes()
    refused = _finetune(scene, base, base, "--steps", 1, "--overwrite")  # --out is the checkpoint it starts from
    assert refused.exit_code == 1 and "is the input" in refused.output and Path(base).read_bytes() == before
    assert _finetune(scene, base, existing, "--steps", 1, "--overwrite").exit_code == 0
    assert torch.load(existing, weights_only=True)["format"] == "insertnerf-checkpoint"


@pytest.mark.slow
def test_render_finetune_caches_the_weights_in_out(tmp_path, base):
    scene = make_scene(tmp_path / "scene", {"train": 6})
    out = tmp_path / "video"
    args = ("render", scene, "--out", out, "--checkpoint", base, "--device", "cpu", "--resolution", 16,
            "--views", 3, "--frames", 2, "--finetune", 0.005)
    first = run(*args)
    assert first.exit_code == 0, first.output
    # The tiny photos give no SfM point: the render tries once, and the fine-tune does not try again.
    assert first.output.count("triangulating SfM points") == 1, first.output
    weights = out / "finetune.pt"
    made = weights.stat().st_mtime_ns
    again = run(*args)
    assert again.exit_code == 0 and "reusing the fine-tuned weights" in again.output
    assert weights.stat().st_mtime_ns == made
    other = run(*args[:-1], 0.006, "--overwrite")  # another budget: fine-tuned again, frames rendered again
    assert other.exit_code == 0 and "reusing" not in other.output and weights.stat().st_mtime_ns != made


def test_a_budget_that_is_not_a_finite_number_is_refused(tmp_path, base):
    """--minutes nan once ran for ever (no elapsed time is >= nan); with --steps 1 a regression exits 0 instead."""
    scene = make_scene(tmp_path / "scene", {"train": 6})
    for value in ("nan", "inf"):
        refused = _finetune(scene, base, tmp_path / "ft.pt", "--steps", 1, "--minutes", value)
        assert refused.exit_code == 2 and "finite" in refused.output and not (tmp_path / "ft.pt").exists()
    refused = run("render", scene, "--out", tmp_path / "video", "--finetune", "nan", "--device", "cpu")
    assert refused.exit_code == 2 and "finite" in refused.output and not (tmp_path / "video").exists()
