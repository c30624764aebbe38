"""Checkpoints: weights_only round trip, atomic writes, and one-line errors for anything wrong."""
from __future__ import annotations

import dataclasses
import pickle

import pytest
import torch

from insertnerf_cli.model.checkpoint import (CHECKPOINT_VERSION, TrainState, average_weights, bundled_checkpoint,
                                       export_weights, load_model, read_checkpoint, save_checkpoint)
from insertnerf_cli.errors import UserError
from insertnerf_cli.model import InsertNeRF
from test_train import TINY


def tiny_model(seed: int = 0) -> InsertNeRF:
    torch.manual_seed(seed)
    return InsertNeRF(TINY)


def one_line(err: pytest.ExceptionInfo) -> str:
    message = str(err.value)
    assert "\n" not in message and message
    return message


@pytest.mark.slow
def test_round_trip_loads_with_weights_only_and_rebuilds_the_model(tmp_path):
    model = tiny_model()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    state = TrainState(step=7, elapsed_s=12.5, optimizer=optimizer.state_dict(),
                       rng={"torch": torch.get_rng_state()}, train_config="{}", best_val_psnr=21.5)
    path = save_checkpoint(tmp_path / "ckpt" / "last.pt", model, TINY, state)
    payload = torch.load(path, weights_only=True)
    assert payload["version"] == CHECKPOINT_VERSION and payload["train"]["step"] == 7
    loaded, config = load_model(path, torch.device("cpu"))
    assert config == TINY and isinstance(loaded, InsertNeRF) and not loaded.training
    for name, tensor in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[name], tensor), name
    back = read_checkpoint(path).train_state
    assert (back.step, back.elapsed_s, back.best_val_psnr) == (7, 12.5, 21.5)
    assert torch.equal(back.rng["torch"], state.rng["torch"])
    assert [p.name for p in path.parent.iterdir()] == ["last.pt"]  # no temporary file left behind


@pytest.mark.parametrize("content", [b"", b"not a checkpoint at all", b"PK\x03\x04broken zip"])
def test_corrupt_files_are_one_line_errors(tmp_path, content):
    path = tmp_path / "bad.pt"
    path.write_bytes(content)
    with pytest.raises(UserError) as err:
        load_model(path, torch.device("cpu"))
    assert "cannot be read" in one_line(err)


def test_truncated_checkpoint_is_a_one_line_error(tmp_path):
    path = save_checkpoint(tmp_path / "ok.pt", tiny_model(), TINY)
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(UserError) as err:
        read_checkpoint(path)
    assert "corrupt" in one_line(err)


class Payload:
    """Anything that is not a tensor or a plain type: weights_only loading must refuse to build it."""


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")
def test_pickled_objects_are_refused(tmp_path):
    path = tmp_path / "evil.pt"
    torch.save({"format": "insertnerf-checkpoint", "version": 1, "payload": Payload()}, path, pickle_protocol=2)
    with pytest.raises(UserError) as err:
        read_checkpoint(path)
    one_line(err)
    path.write_bytes(pickle.dumps({"x": 1}))
    with pytest.raises(UserError):
        read_checkpoint(path)


def test_foreign_newer_or_incompatible_checkpoints_are_refused(tmp_path):
    torch.save({"state_dict": {}}, tmp_path / "foreign.pt")
    with pytest.raises(UserError) as err:
        read_checkpoint(tmp_path / "foreign.pt")
    assert "not an insertnerf checkpoint" in one_line(err)

    path = save_checkpoint(tmp_path / "ok.pt", tiny_model(), TINY)
    payload = torch.load(path, weights_only=True)
    torch.save({**payload, "version": CHECKPOINT_VERSION + 1}, tmp_path / "newer.pt")
    with pytest.raises(UserError) as err:
        read_checkpoint(tmp_path / "newer.pt")
    assert "upgrade" in one_line(err)

    torch.save({**payload, "model_config": {**payload["model_config"], "no_such_field": 1}}, tmp_path / "keys.pt")
    with pytest.raises(UserError) as err:
        read_checkpoint(tmp_path / "keys.pt")
    assert "incompatible" in one_line(err)

    # Weights of a wider model under this config: names match, shapes do not.
    wider = dataclasses.replace(TINY, nerf_width=2 * TINY.nerf_width)
    torch.save({**payload, "model": InsertNeRF(wider).state_dict()}, tmp_path / "shapes.pt")
    with pytest.raises(UserError) as err:
        load_model(tmp_path / "shapes.pt", torch.device("cpu"))
    assert "does not fit" in one_line(err)


def test_a_failed_save_keeps_the_previous_checkpoint(tmp_path):
    path = save_checkpoint(tmp_path / "last.pt", tiny_model(0), TINY)
    before = path.read_bytes()
    broken = TrainState(step=1, elapsed_s=0.0, optimizer={"fn": lambda: None}, rng={}, train_config="{}")
    with pytest.raises(Exception):
        save_checkpoint(path, tiny_model(1), TINY, broken)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["last.pt"]


def test_missing_checkpoint_files_are_one_line_errors(tmp_path):
    with pytest.raises(UserError) as err:
        load_model(tmp_path / "nope.pt", torch.device("cpu"))
    assert "does not exist" in one_line(err)
    try:
        path = bundled_checkpoint()
    except UserError as missing:
        assert "--checkpoint" in str(missing) and "\n" not in str(missing)
    else:
        model, config = load_model(path, torch.device("cpu"))  # the shipped weights must load
        assert isinstance(model, InsertNeRF)


def test_export_keeps_weights_and_config_and_drops_training_state(tmp_path):
    model = tiny_model()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    state = TrainState(step=3, elapsed_s=1.0, optimizer=optimizer.state_dict(), rng={}, train_config="{}")
    source = save_checkpoint(tmp_path / "last.pt", model, TINY, state)
    exported = export_weights(source, tmp_path / "weights.pt")
    copy = read_checkpoint(exported)
    assert copy.train_state is None and copy.model_config == TINY
    for name, tensor in model.state_dict().items():
        assert torch.equal(copy.model_state[name], tensor), name
    assert exported.stat().st_size < source.stat().st_size
    retuned = read_checkpoint(export_weights(source, tmp_path / "retuned.pt", sample_views=12,
                                             consistency_temperature_fine=0.01))
    assert retuned.model_config == dataclasses.replace(TINY, sample_views=12, consistency_temperature_fine=0.01)
    with pytest.raises(ValueError, match="samples_fine"):
        export_weights(source, tmp_path / "broken.pt", samples_fine=4)


@pytest.mark.slow
def test_average_of_two_generators_is_their_midpoint_and_refuses_other_configs(tmp_path):
    a, b = tiny_model(0), tiny_model(1)
    pa = save_checkpoint(tmp_path / "a.pt", a, TINY)
    pb = save_checkpoint(tmp_path / "b.pt", b, TINY)
    soup = read_checkpoint(average_weights([pa, pb], tmp_path / "soup.pt"))
    leaning = read_checkpoint(average_weights([pa, pb], tmp_path / "lean.pt", [3.0, 1.0]))
    assert soup.model_config == TINY and soup.train_state is None
    for name, ta in a.state_dict().items():
        tb = b.state_dict()[name]
        if ta.is_floating_point():
            assert torch.allclose(soup.model_state[name], (ta + tb) / 2, atol=1e-6), name
            assert torch.allclose(leaning.model_state[name], 0.75 * ta + 0.25 * tb, atol=1e-6), name
        else:
            assert torch.equal(soup.model_state[name], ta), name
    other = save_checkpoint(tmp_path / "other.pt", a, dataclasses.replace(TINY, sample_views=12))
    with pytest.raises(UserError) as err:
        average_weights([pa, other], tmp_path / "bad.pt")
    assert "config" in one_line(err)
    with pytest.raises(UserError):
        average_weights([pa, pb], tmp_path / "bad.pt", [0.0, 0.0])
