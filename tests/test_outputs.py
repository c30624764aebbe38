"""Render outputs: uint16 depth round trip, turbo previews, H.264 videos, cameras.json, atomic writes."""
import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.errors import UserError
from insertnerf_cli.exporters.eval_outputs import side_by_side
from insertnerf_cli.exporters.outputs import (depth_to_turbo, depth_to_uint16, ffmpeg_exe, frame_paths, to_uint8,
                                             write_cameras_json, write_frame, write_png, write_video)
from cli_fixtures import video_codec


def test_depth_png_round_trips_as_uint16_steps_of_the_scale(tmp_path):
    depth = np.array([[0.5, 1.2345], [np.nan, 70.0]])
    valid = np.array([[True, True], [True, False]])
    steps, clipped = depth_to_uint16(depth, valid, 1e-3)
    assert steps.dtype == np.uint16 and clipped == 0
    np.testing.assert_array_equal(steps, [[500, 1234], [0, 0]])  # NaN and invalid pixels read as 0
    write_png(tmp_path / "d.png", steps)
    back = iio.imread(tmp_path / "d.png")
    assert back.dtype == np.uint16
    np.testing.assert_array_equal(back, steps)
    np.testing.assert_allclose(back[0] * 1e-3, [0.5, 1.234])


def test_depth_too_far_for_the_scale_is_clipped_and_counted_tiny_depth_stays_valid():
    steps, clipped = depth_to_uint16(np.array([[100.0, 1e-5]]), np.ones((1, 2), bool), 1e-3)
    assert clipped == 1
    np.testing.assert_array_equal(steps, [[65535, 1]])


def test_turbo_preview_near_is_warm_far_is_cool_invalid_is_black():
    depth = np.array([[1.0, 4.0, 2.0]])
    vis = depth_to_turbo(depth, np.array([[True, True, False]]), near=1.0, far=4.0)
    assert vis.dtype == np.uint8 and vis.shape == (1, 3, 3)
    near_rgb, far_rgb = vis[0, 0].astype(int), vis[0, 1].astype(int)
    assert near_rgb[0] > near_rgb[2] and far_rgb[2] > far_rgb[0]  # turbo: red at the top, blue at the bottom
    np.testing.assert_array_equal(vis[0, 2], [0, 0, 0])


@pytest.mark.slow
def test_frame_files_and_h264_video(tmp_path):
    ffmpeg_exe()
    files = []
    for i in range(4):
        rgb = np.zeros((17, 23, 3))  # odd size on purpose: the video pads to even
        rgb[:, : 5 * (i + 1)] = [1.0, 0.5, 0.0]
        paths = frame_paths(tmp_path, i)
        write_frame(paths, rgb, np.full((17, 23), 1000, np.uint16), np.zeros((17, 23, 3), np.uint8))
        assert paths.all_exist() and paths.frame.name == f"{i:05d}.png"
        files.append(paths.frame)
    np.testing.assert_array_equal(iio.imread(files[0])[0, 0], [255, 128, 0])
    video = tmp_path / "video.mp4"
    write_video(video, files, fps=10)
    assert "h264" in video_codec(video)
    frames = list(_read_video(video))
    assert len(frames) == 4 and frames[0].shape == (18, 24, 3)
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]


def _read_video(path):
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    w, h = meta["size"]
    for raw in reader:
        yield np.frombuffer(raw, np.uint8).reshape(h, w, 3)


def test_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    target = tmp_path / "frames" / "00000.png"

    def half_write(path, data):
        open(path, "wb").write(data[:10])  # some bytes reach the disk, then the user presses Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(Path, "write_bytes", half_write)
    with pytest.raises(KeyboardInterrupt):
        write_png(target, np.zeros((2, 2, 3), np.uint8))
    assert list(target.parent.iterdir()) == []
    with pytest.raises(UserError):
        write_video(tmp_path / "v.mp4", [], fps=10)


def test_cameras_json_is_nerfstudio_style(tmp_path):
    c2w = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    c2w[1, 0, 3] = 2.0
    cams = Cameras(intrinsics(30.0, 30.0, 16.0, 12.0).expand(2, 3, 3), c2w, 24, 32)
    near, far = torch.full((2,), 0.5, dtype=torch.float64), torch.full((2,), 6.0, dtype=torch.float64)
    write_cameras_json(tmp_path / "cameras.json", cams, near, far, 2e-4, extra={"path": "orbit"})
    data = json.loads((tmp_path / "cameras.json").read_text())
    assert data["depth_unit_scale_factor"] == 2e-4 and data["path"] == "orbit" and data["depth_format"] == "png16"
    assert data["fl_x"] == 30.0 and data["w"] == 32 and data["h"] == 24
    assert [f["file_path"] for f in data["frames"]] == ["frames/00000.png", "frames/00001.png"]
    assert data["frames"][1]["depth_file_path"] == "depth/00001.png"
    # OpenGL c2w: the OpenCV identity has its y and z axes flipped.
    gl = np.array(data["frames"][1]["transform_matrix"])
    np.testing.assert_allclose(gl[:3, :3], np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_allclose(gl[:3, 3], [2.0, 0.0, 0.0])


def test_side_by_side_layout():
    render = np.full((4, 5, 3), 0.5)
    truth = np.full((4, 5, 3), 0.5)
    out = side_by_side(render, truth)
    assert out.shape == (4, 15, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out[:, :5], to_uint8(render))
    np.testing.assert_array_equal(out[:, 5:10], to_uint8(truth))
    # Zero error sits at the bottom of the turbo map (dark blue), a big error at the top (dark red).
    big = side_by_side(np.zeros((4, 5, 3)), np.ones((4, 5, 3)))
    assert out[0, 10, 2] > out[0, 10, 0] and big[0, 10, 0] > big[0, 10, 2]
