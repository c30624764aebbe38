"""train --init: a model with other sample counts starts from a checkpoint's weights (training/warm_start.py)."""
from __future__ import annotations

import dataclasses
import json

import pytest
import torch
from click.testing import CliRunner

from insertnerf_cli.model.checkpoint import read_checkpoint, save_checkpoint
from insertnerf_cli.cli.main import cli
from insertnerf_cli.config import config_to_json
from insertnerf_cli.errors import UserError
from insertnerf_cli.model import InsertNeRF
from insertnerf_cli.training.warm_start import warm_start
from model_fixtures import TINY
from test_train import SIZE, write_scene

FEWER = dataclasses.replace(TINY, samples_coarse=8, samples_fine=4, separate_fine_head=True)


@pytest.fixture()
def tiny_checkpoint(tmp_path):
    torch.manual_seed(123)  # not the training seed: a random start must differ from these weights
    model = InsertNeRF(TINY)
    path = tmp_path / "tiny.pt"
    save_checkpoint(path, model, TINY)
    return path, model


@pytest.fixture()
def data(tmp_path):
    root = tmp_path / "data"
    for s in range(2):
        write_scene(root / f"scene_{s}", views=6, seed=s)
    return root


@pytest.mark.slow
def test_same_config_copies_every_tensor(tiny_checkpoint):
    path, source = tiny_checkpoint
    target = InsertNeRF(TINY)
    report = warm_start(target, read_checkpoint(path))
    assert report.resampled == 0 and report.copied == len(source.state_dict())
    for name, value in source.state_dict().items():
        torch.testing.assert_close(target.state_dict()[name], value)


@pytest.mark.slow
def test_fewer_samples_keep_the_generated_layers_on_inputs_constant_along_the_ray(tiny_checkpoint):
    path, source = tiny_checkpoint
    target = InsertNeRF(FEWER)
    report = warm_start(target, read_checkpoint(path))
    assert report.resampled > 0
    # A sum over the samples keeps its value: per-ray weights generated from a condition that is the same at every
    # sample are the same whatever the sample count. The separate fine head starts as the shared coarse head.
    cond = torch.rand(5, 1, source.coarse_head.conditioners[1].weights.features.in_features)
    for head, samples in ((target.coarse_head, FEWER.samples_coarse), (target.fine_head, FEWER.samples_fine)):
        theirs = source.coarse_head.conditioners[1].weights(cond.expand(-1, TINY.samples_coarse, -1))
        ours = head.conditioners[1].weights(cond.expand(-1, samples, -1))
        torch.testing.assert_close(ours, theirs)


def test_another_architecture_is_one_clear_error(tiny_checkpoint):
    path, _ = tiny_checkpoint
    with pytest.raises(UserError, match="only the sample counts may differ"):
        warm_start(InsertNeRF(dataclasses.replace(TINY, nerf_width=8)), read_checkpoint(path))
    with pytest.raises(UserError, match="another architecture"):
        warm_start(InsertNeRF(dataclasses.replace(TINY, nerf_layers=4)), read_checkpoint(path))


@pytest.mark.slow
def test_train_init_starts_from_the_checkpoint_and_records_it(tiny_checkpoint, data, tmp_path):
    path, source = tiny_checkpoint
    config = tmp_path / "fewer.json"
    config.write_text(json.dumps(config_to_json(FEWER)))
    out = tmp_path / "run"
    result = CliRunner().invoke(cli, ["train", str(data), "--out", str(out), "--device", "cpu", "--model-config",
                                      str(config), "--init", str(path), "--steps", "1", "--lr", "1e-12", "--rays",
                                      "16", "--resolution", str(SIZE), "--val-every", "1000"])
    assert result.exit_code == 0, result.output
    assert "resampled to this model's sample counts" in result.output
    saved = read_checkpoint(out / "checkpoints" / "last.pt")
    assert json.loads(saved.train_state.train_config)["init"] == str(path.resolve())
    name = next(n for n in saved.model_state if n.startswith("encoder."))
    # one step at a learning rate of 1e-12 leaves the copied weights where the checkpoint had them
    torch.testing.assert_close(saved.model_state[name], source.state_dict()[name], atol=1e-6, rtol=0)


@pytest.mark.slow
def test_init_inside_the_run_folder_is_refused_before_overwrite_could_delete_it(tiny_checkpoint, data, tmp_path):
    path, _ = tiny_checkpoint
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    inside = run / "checkpoints" / "last.pt"
    inside.write_bytes(path.read_bytes())
    before = inside.read_bytes()
    result = CliRunner().invoke(cli, ["train", str(data), "--out", str(run), "--init", str(inside), "--overwrite",
                                      "--steps", "1", "--device", "cpu"])
    assert result.exit_code == 1 and "--init checkpoint" in result.output
    assert inside.read_bytes() == before


def test_a_nerfpp_background_starts_as_the_fine_head_reading_the_inverted_spheres_direction(tiny_checkpoint):
    """A NeRF checkpoint into a NeRF++ model: the background head is a copy of the fine head, except that the
    first layer's rows that read gamma(x, y, z) read gamma of the inverted sphere's direction, and those of its
    inverse distance are zero (unread at first)."""
    path, source = tiny_checkpoint
    target = InsertNeRF(dataclasses.replace(TINY, backbone="nerfpp", samples_background=TINY.samples_fine))
    warm_start(target, read_checkpoint(path))
    theirs, ours = source.fine_head.state_dict(), target.background_head.state_dict()
    rows = "conditioners.0.weights.features.weight"
    blocks = 1 + 2 * TINY.pe_freqs_pos  # gamma: [c, sin(2^k c), cos(2^k c)], k-major
    placed = ours[rows].reshape(blocks, 4, -1)
    torch.testing.assert_close(placed[:, :3], theirs[rows].reshape(blocks, 3, -1))
    assert not placed[:, 3].any()
    bias = ours["conditioners.0.weights.features.bias"].reshape(blocks, 4)
    torch.testing.assert_close(bias[:, :3], theirs["conditioners.0.weights.features.bias"].reshape(blocks, 3))
    for name, value in theirs.items():
        if name not in (rows, "conditioners.0.weights.features.bias"):
            torch.testing.assert_close(ours[name], value)
