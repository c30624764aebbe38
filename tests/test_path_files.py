"""`render --path FILE`: a nerfstudio camera_path.json or a transforms.json of target cameras, followed exactly."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from cli_fixtures import make_checkpoint, make_scene, ring_cameras, run

from insertnerf_cli.cameras.camera import opengl_to_opencv

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def scene_and_checkpoint(tmp_path_factory):
    root = tmp_path_factory.mktemp("pathfile")
    return make_scene(root / "scene", {"train": 6}), make_checkpoint(root / "tiny.pt")


def _keyframes() -> np.ndarray:
    """[3, 4, 4] OpenGL camera-to-world of three cameras between the scene's inputs, a little closer in."""
    cams = ring_cameras(12, radius=1.7)
    return opengl_to_opencv(cams.c2w[[1, 3, 5]]).numpy()  # the flip is its own inverse


def _camera_path(c2w_gl: np.ndarray, fov: float = 50.0, **top) -> dict:
    return {"camera_type": "perspective", "render_height": 12, "render_width": 16, "fps": 12, "seconds": 0.25,
            "keyframes": [{"matrix": m.flatten().tolist(), "fov": fov} for m in c2w_gl],
            "camera_path": [{"camera_to_world": m.flatten().tolist(), "fov": fov, "aspect": 16 / 12} for m in c2w_gl],
            **top}


def render_command(scene: Path, ckpt: Path, out: Path, path: Path, *extra):
    return run("render", scene, "--out", out, "--checkpoint", ckpt, "--device", "cpu", "--views", 2,
               "--path", path, *extra)


@pytest.mark.slow
def test_a_nerfstudio_camera_path_renders_its_cameras_exactly(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    c2w = _keyframes()
    path = tmp_path / "camera_path.json"
    path.write_text(json.dumps(_camera_path(c2w)))
    result = render_command(scene, ckpt, tmp_path / "views", path)
    assert result.exit_code == 0, result.output
    cams = json.loads((tmp_path / "views" / "cameras.json").read_text())
    written = np.array([f["transform_matrix"] for f in cams["frames"]])
    np.testing.assert_allclose(written, c2w, atol=1e-6, rtol=0)
    assert cams["path"] == "file" and cams["fps"] == 12 and cams["path_file"] == str(path.resolve())
    focal = 6.0 / math.tan(math.radians(25.0))  # half the height over tan(fov / 2)
    assert all(f.get("fl_y", cams.get("fl_y")) == pytest.approx(focal) for f in cams["frames"])
    assert len(list((tmp_path / "views" / "frames").glob("*.png"))) == 3


@pytest.mark.slow
def test_a_transforms_file_of_target_cameras_renders_too(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    c2w = _keyframes()[:2]
    path = tmp_path / "targets.json"
    path.write_text(json.dumps({"fl_x": 14.0, "w": 16, "h": 12,
                                "frames": [{"transform_matrix": m.tolist()} for m in c2w]}))
    result = render_command(scene, ckpt, tmp_path / "views", path)
    assert result.exit_code == 0, result.output
    written = np.array([f["transform_matrix"] for f in
                        json.loads((tmp_path / "views" / "cameras.json").read_text())["frames"]])
    np.testing.assert_allclose(written, c2w, atol=1e-6, rtol=0)


def _singular() -> dict:
    c2w = _keyframes()
    c2w[1, :3, :3] = 0.0
    return _camera_path(c2w)


@pytest.mark.parametrize("content, words", [
    ("{not json", "is not JSON"),
    (json.dumps({"render_height": 12, "render_width": 16}), "neither 'camera_path'"),
    (json.dumps({**_camera_path(_keyframes()), "camera_path": [{"fov": 50}]}), "has no 'camera_to_world'"),
    (json.dumps({k: v for k, v in _camera_path(_keyframes()).items() if k != "render_height"}), "render_height"),
    (json.dumps(_singular()), "not a rigid camera pose"),
    (json.dumps(_camera_path(_keyframes(), fov=0.0)), "fov"),
])
def test_a_bad_path_file_is_one_line_and_exit_1(scene_and_checkpoint, tmp_path, content, words):
    scene, ckpt = scene_and_checkpoint
    path = tmp_path / "camera_path.json"
    path.write_text(content)
    result = render_command(scene, ckpt, tmp_path / "views", path)
    assert result.exit_code == 1, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and words in lines[0] and "Traceback" not in result.output
    assert not (tmp_path / "views").exists()


def test_path_is_a_kind_or_an_existing_file(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    result = render_command(scene, ckpt, tmp_path / "views", tmp_path / "nowhere.json")
    assert result.exit_code == 1 and "no such file" in result.output
    path = tmp_path / "camera_path.json"
    path.write_text(json.dumps(_camera_path(_keyframes())))
    result = render_command(scene, ckpt, tmp_path / "views", path, "--frames", 5)
    assert result.exit_code == 1 and "--frames does not apply" in result.output
