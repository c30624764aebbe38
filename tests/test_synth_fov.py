"""insertnerf synth --fov: the long side's field of view drawn from the range asked for; the default's datasets
keep their manifests byte for byte, and a narrow range gives the same scene seen through a longer lens."""
from __future__ import annotations

import json
import math

import pytest
import torch
from click.testing import CliRunner

from insertnerf_cli.cli.main import cli
from insertnerf_cli.errors import UserError
from insertnerf_cli.scenes import load_scene
from insertnerf_cli.synth import SceneSpec, SynthOptions, generate_dataset
from insertnerf_cli.synth.layouts import FOV_RANGE
from insertnerf_cli.synth.scene import scene_cameras, scene_world

RES = 40

pytestmark = pytest.mark.usefixtures("one_thread")


def _long_side_fov(scene_dir) -> float:
    """Degrees the long side of the scene's first camera sees, from the focal length load_scene reads back."""
    cameras = load_scene(scene_dir).cameras
    long_side = max(cameras.height, cameras.width)
    focal = float(cameras.K[0, 0, 0] if cameras.width >= cameras.height else cameras.K[0, 1, 1])
    return math.degrees(2 * math.atan(0.5 * long_side / focal))


@pytest.mark.slow
def test_every_scene_sees_a_field_of_view_inside_the_range_asked_for(tmp_path):
    result = CliRunner().invoke(cli, ["synth", str(tmp_path / "s"), "--scenes", "3", "--views", "3",
                                      "--resolution", str(RES), "--workers", "1", "--layout", "object",
                                      "--fov", "20:24"])
    assert result.exit_code == 0, result.output
    for k in range(3):
        assert 20.0 - 0.1 <= _long_side_fov(tmp_path / "s" / f"scene_{k:05d}") <= 24.0 + 0.1
    manifest = json.loads((tmp_path / "s" / "manifest.json").read_text())
    assert manifest["options"]["fov"] == [20.0, 24.0]
    assert all(s["fov"] == [20.0, 24.0] for s in manifest["scenes"])
    assert SceneSpec.from_json(manifest["scenes"][0]).fov == (20.0, 24.0)


@pytest.mark.slow
def test_the_default_range_is_left_out_of_the_manifest_so_older_datasets_resume(tmp_path):
    options = SynthOptions(scenes=1, views=3, test_views=1, resolution=RES, layout="object", seed=5)
    generate_dataset(tmp_path / "d", options, workers=1)
    manifest = json.loads((tmp_path / "d" / "manifest.json").read_text())
    assert "fov" not in manifest["options"] and "fov" not in manifest["scenes"][0]
    assert SceneSpec.from_json(manifest["scenes"][0]).fov == FOV_RANGE
    # The same options through the command line (--fov 35:75 is the default) resume it instead of refusing.
    result = CliRunner().invoke(cli, ["synth", str(tmp_path / "d"), "--scenes", "1", "--views", "3", "--test-views",
                                      "1", "--resolution", str(RES), "--workers", "1", "--layout", "object",
                                      "--seed", "5", "--fov", "35:75"])
    assert result.exit_code == 0, result.output
    assert "already there" in result.output


@pytest.mark.slow
def test_a_narrower_range_frames_the_same_scene_through_a_longer_lens(tmp_path):
    base = dict(scenes=1, views=3, test_views=1, resolution=RES, layout="object", seed=2)  # an open stage
    generate_dataset(tmp_path / "wide", SynthOptions(**base), workers=1)
    generate_dataset(tmp_path / "narrow", SynthOptions(**base, fov=(25.0, 25.0)), workers=1)
    wide, narrow = (json.loads((tmp_path / d / "scene_00000" / "scene.json").read_text())
                    for d in ("wide", "narrow"))
    assert wide["world"] == narrow["world"]  # the seed draws the same world whatever the lens
    assert abs(_long_side_fov(tmp_path / "narrow" / "scene_00000") - 25.0) < 0.1
    assert narrow["frame"]["focal"] > wide["frame"]["focal"]
    # The rig stands back so that the subject fills the frame alike (inside an enclosure: up to its walls).
    distance = {}
    for name, fov in (("wide", FOV_RANGE), ("narrow", (25.0, 25.0))):
        spec = SynthOptions(**base, fov=fov).spec(0)
        world = scene_world(spec)
        eyes = scene_cameras(spec, world)[0].c2w[:, :3, 3].double()
        distance[name] = float((eyes - torch.as_tensor(world.stage.center)).norm(dim=-1).mean())
    assert distance["narrow"] > 1.5 * distance["wide"]


@pytest.mark.parametrize("fov", ["abc", "30:20", "0:10", "10:200", "1:2:3"])
def test_a_bad_range_is_one_line_and_writes_nothing(tmp_path, fov):
    result = CliRunner().invoke(cli, ["synth", str(tmp_path / "s"), "--scenes", "1", "--fov", fov])
    assert result.exit_code != 0 and "--fov" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "s").exists()


def test_the_library_refuses_a_bad_range_too():
    with pytest.raises(UserError, match="--fov"):
        SynthOptions(fov=(60.0, 30.0))
