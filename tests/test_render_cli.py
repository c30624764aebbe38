"""`insertnerf render` through click's CliRunner on a tiny Blender scene with a tiny random-init checkpoint."""
from __future__ import annotations

import json
from pathlib import Path

import imageio.v3 as iio
import imageio_ffmpeg
import numpy as np
import pytest

from insertnerf_cli.model.checkpoint import bundled_checkpoint, checkpoint_sha256
from insertnerf_cli.model import InsertNeRF
from insertnerf_cli.exporters.outputs import STATE_FILE, depth_scale_for
from cli_fixtures import HEIGHT, WIDTH, make_checkpoint, make_scene, render_command, run, video_codec

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def scene_and_checkpoint(tmp_path_factory):
    root = tmp_path_factory.mktemp("render")
    return make_scene(root / "scene", {"train": 6}), make_checkpoint(root / "tiny.pt")


def _mtimes(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in sorted(folder.iterdir())}


@pytest.mark.slow
def test_render_writes_every_output_with_the_right_types(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / "views"
    result = render_command(scene, ckpt, out, "--frames", 3, "--fps", 5)
    assert result.exit_code == 0, result.output
    assert "3 frames (orbit, 16x12)" in result.output and "clipped" not in result.output
    cams = json.loads((out / "cameras.json").read_text())
    scale = cams["depth_unit_scale_factor"]
    assert scale == depth_scale_for(4.0)  # the scene's far bound
    for i in range(3):
        rgb = iio.imread(out / "frames" / f"{i:05d}.png")
        depth = iio.imread(out / "depth" / f"{i:05d}.png")
        vis = iio.imread(out / "depth_vis" / f"{i:05d}.png")
        assert rgb.dtype == np.uint8 and rgb.shape == (HEIGHT // 2, WIDTH // 2, 3)
        assert depth.dtype == np.uint16 and depth.shape == (HEIGHT // 2, WIDTH // 2)
        assert vis.dtype == np.uint8 and vis.shape == (HEIGHT // 2, WIDTH // 2, 3)
        # Valid depths lie within the scene's bounds (user units, the scene was not rescaled by the writer).
        valid = depth[depth > 0] * scale
        assert valid.size == 0 or (valid.min() >= 0.5 - scale and valid.max() <= 4.0 + scale)
    for video in ("video.mp4", "depth.mp4"):
        assert "h264" in video_codec(out / video)
        assert imageio_ffmpeg.count_frames_and_secs(str(out / video))[0] == 3
    assert cams["path"] == "orbit"
    assert len(cams["frames"]) == 3 and cams["frames"][2]["file_path"] == "frames/00002.png"
    # The path goes back to the user's units: orbit frames sit on the input ring (radius 2, height 1).
    centres = np.array([f["transform_matrix"] for f in cams["frames"]])[:, :3, 3]
    np.testing.assert_allclose(np.linalg.norm(centres[:, :2], axis=1), 2.0, atol=1e-6)
    np.testing.assert_allclose(centres[:, 2], 1.0, atol=1e-6)
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]


@pytest.mark.slow
def test_depth_is_in_the_scene_units(scene_and_checkpoint, tmp_path):
    # The same scene with every length doubled normalises to the same scene: the frames match and the depths
    # read back through cameras.json's scale double.
    scene, ckpt = scene_and_checkpoint
    double = make_scene(tmp_path / "double", {"train": 6}, scale=2.0)
    assert render_command(scene, ckpt, tmp_path / "a", "--frames", 1).exit_code == 0
    assert render_command(double, ckpt, tmp_path / "b", "--frames", 1).exit_code == 0
    scale_a, scale_b = (json.loads((tmp_path / d / "cameras.json").read_text())["depth_unit_scale_factor"]
                        for d in "ab")
    depth_a = iio.imread(tmp_path / "a" / "depth" / "00000.png") * scale_a
    depth_b = iio.imread(tmp_path / "b" / "depth" / "00000.png") * scale_b
    valid = (depth_a > 0) & (depth_b > 0)
    assert valid.mean() > 0.5, "too few valid depth pixels to compare"
    assert np.abs(depth_b[valid] - 2 * depth_a[valid]).max() <= scale_b + 2 * scale_a  # one step of rounding each
    rgb_a, rgb_b = (iio.imread(tmp_path / d / "frames" / "00000.png").astype(int) for d in "ab")
    assert np.abs(rgb_a - rgb_b).max() <= 1


@pytest.mark.slow
def test_interrupted_render_resumes_only_missing_frames(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / "views"
    assert render_command(scene, ckpt, out, "--frames", 4).exit_code == 0
    before = _mtimes(out / "frames")
    for sub in ("frames", "depth_vis"):  # as if the run had been stopped while frames 1 and 3 were written
        (out / sub / "00001.png").unlink()
    (out / "frames" / "00003.png").unlink()
    result = render_command(scene, ckpt, out, "--frames", 4)
    assert result.exit_code == 0, result.output
    assert "rendered 2 (2 kept from the earlier run)" in result.output
    after = _mtimes(out / "frames")
    assert after["00000.png"] == before["00000.png"] and after["00002.png"] == before["00002.png"]
    assert sorted(after) == [f"{i:05d}.png" for i in range(4)]
    assert (out / "depth_vis" / "00001.png").is_file()


@pytest.mark.slow
def test_other_settings_need_overwrite(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / "views"
    assert render_command(scene, ckpt, out, "--frames", 2).exit_code == 0
    state = (out / STATE_FILE).read_text()
    refused = render_command(scene, ckpt, out, "--frames", 3)
    assert refused.exit_code == 1 and "--overwrite" in refused.output and "Traceback" not in refused.output
    assert (out / STATE_FILE).read_text() == state and not (out / "frames" / "00002.png").exists()
    replaced = render_command(scene, ckpt, out, "--frames", 3, "--overwrite")
    assert replaced.exit_code == 0 and "rendered 3" in replaced.output
    # --overwrite with the same settings renders everything again instead of resuming.
    again = render_command(scene, ckpt, out, "--frames", 3, "--overwrite")
    assert "rendered 3" in again.output and "kept" not in again.output


@pytest.mark.slow
def test_frames_of_a_changed_path_are_not_mixed(tmp_path):
    # Same command, but the scene's poses changed in between: the kept frames would belong to another path.
    scene, ckpt = make_scene(tmp_path / "scene", {"train": 6}), make_checkpoint(tmp_path / "tiny.pt")
    out = tmp_path / "views"
    assert render_command(scene, ckpt, out, "--frames", 2).exit_code == 0
    (out / "frames" / "00001.png").unlink()
    meta = json.loads((scene / "transforms_train.json").read_text())
    meta["frames"][0]["transform_matrix"][2][3] += 0.3  # raise the first camera
    (scene / "transforms_train.json").write_text(json.dumps(meta))
    result = render_command(scene, ckpt, out, "--frames", 2)
    assert result.exit_code == 1 and "different camera path" in result.output
    assert render_command(scene, ckpt, out, "--frames", 2, "--overwrite").exit_code == 0


@pytest.mark.slow
def test_depth_maps_of_another_scale_are_not_mixed(scene_and_checkpoint, tmp_path):
    # A render resumed after insertnerf changed how far a frame's bound reaches: the kept depth PNGs were written
    # at the old scale, which the new cameras.json would misread.
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / "views"
    assert render_command(scene, ckpt, out, "--frames", 2).exit_code == 0
    (out / "frames" / "00001.png").unlink()
    kept = (out / "depth" / "00000.png").read_bytes()
    cams = json.loads((out / "cameras.json").read_text())
    cams["depth_unit_scale_factor"] *= 2
    (out / "cameras.json").write_text(json.dumps(cams))
    result = render_command(scene, ckpt, out, "--frames", 2)
    assert result.exit_code == 1 and "depth scale" in result.output and "Traceback" not in result.output
    assert (out / "depth" / "00000.png").read_bytes() == kept and not (out / "frames" / "00001.png").exists()
    assert render_command(scene, ckpt, out, "--frames", 2, "--overwrite").exit_code == 0


@pytest.mark.slow
def test_encodings_are_reused_while_the_reference_views_repeat(scene_and_checkpoint, tmp_path, monkeypatch):
    scene, ckpt = scene_and_checkpoint
    calls = []
    original = InsertNeRF.encode

    def counted(self, views):
        calls.append(len(views))
        return original(self, views)

    monkeypatch.setattr(InsertNeRF, "encode", counted)
    # All 6 views as references for every frame: one encoding serves the whole orbit.
    assert render_command(scene, ckpt, tmp_path / "all", "--frames", 4, "--views", 6).exit_code == 0
    assert calls == [6]


def test_refuses_a_foreign_non_empty_folder(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / "precious"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    result = render_command(scene, ckpt, out, "--frames", 2)
    assert result.exit_code == 1 and "already holds other files" in result.output
    assert (out / "notes.txt").read_text() == "keep me" and not (out / "frames").exists()


@pytest.mark.slow
def test_input_path_and_spiral_by_layout(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    result = render_command(scene, ckpt, tmp_path / "input", "--path", "input", "--resolution", 8)
    assert result.exit_code == 0 and "6 frames (input" in result.output
    inputs = json.loads((scene / "transforms_train.json").read_text())["frames"]
    rendered = json.loads((tmp_path / "input" / "cameras.json").read_text())["frames"]
    np.testing.assert_allclose([f["transform_matrix"] for f in rendered], [f["transform_matrix"] for f in inputs],
                               atol=1e-9)
    # A forward-facing scene gets a spiral by default; an object-centric one refuses a spiral with advice.
    forward = make_scene(tmp_path / "forward", {"train": 6}, layout="forward")
    spiral = render_command(forward, ckpt, tmp_path / "spiral", "--frames", 2)
    assert spiral.exit_code == 0 and "2 frames (spiral" in spiral.output, spiral.output
    refused = render_command(scene, ckpt, tmp_path / "no-spiral", "--path", "spiral", "--frames", 2)
    assert refused.exit_code == 1 and "--path orbit" in refused.output
    assert not (tmp_path / "no-spiral").exists()  # refused before the output folder was made


def test_no_ffmpeg_fails_before_any_work(scene_and_checkpoint, tmp_path, monkeypatch):
    scene, ckpt = scene_and_checkpoint
    for exe in (str(tmp_path / "no-such-ffmpeg"), "/bin/false"):
        monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", exe)
        result = render_command(scene, ckpt, tmp_path / "out", "--frames", 2)
        assert result.exit_code == 1 and "ffmpeg" in result.output and "Traceback" not in result.output
        assert not (tmp_path / "out").exists()


def test_bad_input_is_one_line_error(scene_and_checkpoint, tmp_path):
    _, ckpt = scene_and_checkpoint
    empty = tmp_path / "empty"
    empty.mkdir()
    result = render_command(empty, ckpt, tmp_path / "out", "--frames", 2)
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert result.output.startswith("Error:") and len(result.output.strip().splitlines()) == 1


@pytest.mark.slow
@pytest.mark.parametrize("model", ["full", "fast"])
def test_model_renders_with_bundled_weights_and_excludes_checkpoint(scene_and_checkpoint, tmp_path, model):
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / model
    result = run("render", scene, "--out", out, "--model", model, "--device", "cpu", "--resolution", 16,
                 "--views", 2, "--frames", 1)
    assert result.exit_code == 0, result.output
    assert (out / "frames" / "00000.png").is_file()
    state = json.loads((out / STATE_FILE).read_text())
    assert state["checkpoint_sha256"] == checkpoint_sha256(bundled_checkpoint(model))
    # Naming the default model beside --checkpoint is refused too: two sources of weights, whichever they are.
    both = render_command(scene, ckpt, tmp_path / "both", "--model", model)
    assert both.exit_code == 1 and "pass one of them" in both.output
    assert not (tmp_path / "both").exists()


@pytest.mark.slow
def test_backbone_picks_the_bundled_nerfpp_generator_and_must_match_a_checkpoint(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / "nerfpp"
    result = run("render", scene, "--out", out, "--backbone", "nerfpp", "--device", "cpu", "--resolution", 16,
                 "--views", 2, "--frames", 1)
    assert result.exit_code == 0, result.output
    state = json.loads((out / STATE_FILE).read_text())
    assert state["checkpoint_sha256"] == checkpoint_sha256(bundled_checkpoint("fast", "nerfpp"))
    # The test checkpoint has the NeRF backbone: asking for the other one beside it is refused before any work.
    other = render_command(scene, ckpt, tmp_path / "other", "--backbone", "nerfpp")
    assert other.exit_code == 1 and "not --backbone nerfpp" in other.output
    assert len(other.output.strip().splitlines()) == 1 and not (tmp_path / "other").exists()
    assert render_command(scene, ckpt, tmp_path / "same", "--backbone", "nerf", "--frames", 1).exit_code == 0
    full = run("render", scene, "--out", tmp_path / "full", "--model", "full", "--backbone", "nerfpp")
    assert full.exit_code == 1 and "no bundled full generator" in full.output


@pytest.mark.slow
def test_exact_and_default_renders_are_separate_runs(scene_and_checkpoint, tmp_path):
    # --exact changes the frames, so a re-run with it must re-render instead of resuming the other run's frames.
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / "views"
    assert render_command(scene, ckpt, out, "--frames", 1).exit_code == 0
    again = render_command(scene, ckpt, out, "--frames", 1, "--exact")
    assert again.exit_code == 1 and "--overwrite" in again.output
