"""insertnerf synth --supports: 360 subjects stand on a plinth, a pedestal or a table whose top meets the subject and
whose foot is the floor; without it the scenes and the manifest are those of earlier versions."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from insertnerf_cli.cli.main import cli
from insertnerf_cli.synth import SceneSpec, SynthOptions
from insertnerf_cli.synth.compose import compose_360
from insertnerf_cli.synth.layouts import RIGS, random_frame

pytestmark = pytest.mark.usefixtures("one_thread")


def _split(world):
    """(the subject's vertices, the support's vertices) of a 360 world with a support: the subject is drawn first,
    the support next, the surroundings (walls, furniture, scenery) after them."""
    kinds = [o.shape.kind for o in world.objects]
    first = next(i for i, k in enumerate(kinds) if k.startswith("support"))
    last = max(i for i, k in enumerate(kinds) if k.startswith("support"))
    return (np.concatenate([o.world_vertices() for o in world.objects[:first]]),
            np.concatenate([o.world_vertices() for o in world.objects[first:last + 1]]))


@pytest.mark.parametrize("seed", range(6))
def test_the_support_carries_the_subject_from_the_floor_and_the_cameras_stay_clear_of_it(seed):
    world = compose_360(np.random.default_rng(seed), supports=True)
    subject, support = _split(world)
    assert world.description["support"] in ("plinth", "pedestal", "table")
    # Its top is where the subject's lowest point stands, its foot on the stage's floor, below the subject.
    assert support[:, 2].max() == pytest.approx(subject[:, 2].min(), abs=1e-6)
    assert support[:, 2].min() == pytest.approx(world.stage.ground, abs=1e-6)
    assert 0.5 - 1e-6 <= subject[:, 2].min() - world.stage.ground <= 1.3 + 1e-6
    eyes = RIGS["360"](np.random.default_rng(seed), world.stage, random_frame(np.random.default_rng(seed), 64,
                                                                              (4 / 3,)), 30).centers.numpy()
    low, high = support.min(axis=0), support.max(axis=0)
    assert not np.any(np.all((eyes > low) & (eyes < high), axis=1))


def test_without_supports_the_world_is_the_one_of_earlier_versions():
    plain = compose_360(np.random.default_rng(3))
    again = compose_360(np.random.default_rng(3), supports=False)
    assert "support" not in plain.description
    assert [o.shape.kind for o in plain.objects] == [o.shape.kind for o in again.objects]
    assert all(np.array_equal(a.translation, b.translation) for a, b in zip(plain.objects, again.objects))


def test_supports_are_recorded_only_when_on_and_read_back():
    assert "supports" not in SynthOptions(layout="360").to_json()
    on = SynthOptions(layout="360", supports=True)
    assert on.to_json()["supports"] is True
    spec = on.spec(0)
    assert spec.supports and SceneSpec.from_json(json.loads(json.dumps(spec.to_json()))) == spec
    assert "supports" not in SynthOptions(layout="360").spec(0).to_json()


@pytest.mark.slow
def test_cli_supports_writes_a_scene_that_names_its_support(tmp_path):
    result = CliRunner().invoke(cli, ["synth", str(tmp_path / "d"), "--scenes", "1", "--views", "3", "--test-views",
                                      "1", "--resolution", "32", "--workers", "1", "--layout", "360", "--seed", "2",
                                      "--supports"])
    assert result.exit_code == 0, result.output
    record = json.loads((tmp_path / "d" / "scene_00000" / "scene.json").read_text())
    assert record["world"]["support"] in ("plinth", "pedestal", "table") and record["spec"]["supports"] is True
