"""`render --pointcloud`: every frame's valid depth lifted to coloured points in the scene's units and axes."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import trimesh
from cli_fixtures import make_checkpoint, make_scene, run

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.exporters.pointcloud import frame_points, subsample

pytestmark = pytest.mark.usefixtures("one_thread")


def test_points_of_a_wall_lie_on_the_wall_with_their_pixels_colours():
    # A camera at (1, 2, 3) looking down +z (OpenCV) at a wall 5 units away: every point has z = 8.
    c2w = torch.eye(4, dtype=torch.float64)[None].clone()
    c2w[0, :3, 3] = torch.tensor([1.0, 2.0, 3.0])
    camera = Cameras(intrinsics(10.0, 10.0, 4.0, 3.0)[None], c2w, 6, 8)
    depth = np.full((6, 8), 5.0)
    depth[0, 0] = np.nan  # invalid: no point
    rgb = np.arange(6 * 8 * 3, dtype=np.uint8).reshape(6, 8, 3)
    points, colours = frame_points(camera, depth, rgb)
    assert points.shape == (47, 3) and colours.shape == (47, 3)
    np.testing.assert_allclose(points[:, 2], 8.0)
    # Pixel (row 3, col 4)'s centre is (4.5, 3.5): half a pixel right and down of the principal point.
    row = 3 * 8 + 4 - 1  # minus the invalid first pixel
    np.testing.assert_allclose(points[row], [1.0 + 0.5 * 5 / 10, 2.0 + 0.5 * 5 / 10, 8.0])
    np.testing.assert_array_equal(colours[row], rgb[3, 4])


def test_subsample_keeps_at_most_the_limit_the_same_way_every_time():
    points, colours = np.random.default_rng(1).random((100, 3)), np.zeros((100, 3), np.uint8)
    a, _ = subsample(points, colours, 10)
    b, _ = subsample(points, colours, 10)
    assert len(a) == 10 and np.array_equal(a, b) and subsample(points, colours, 500)[0] is points


@pytest.mark.slow
def test_render_pointcloud_loads_with_trimesh_in_the_scene_units(tmp_path):
    unit = 1e4
    scene = make_scene(tmp_path / "scene", {"train": 6}, scale=unit)  # cameras on a ring of radius 2 units
    ckpt = make_checkpoint(tmp_path / "tiny.pt")
    out = tmp_path / "views"
    result = run("render", scene, "--out", out, "--checkpoint", ckpt, "--device", "cpu", "--resolution", 16,
                 "--views", 2, "--frames", 3, "--pointcloud", "--pointcloud-points", 300)
    assert result.exit_code == 0, result.output
    cloud = trimesh.load(out / "pointcloud.ply")
    assert isinstance(cloud, trimesh.PointCloud) and len(cloud.vertices) == 300
    assert "(300 points)" in result.output
    assert cloud.colors.shape == (300, 4) and cloud.colors[:, :3].std() > 0
    # Each point lies along its frame's camera rays between the scene's near and far bounds (0.5 and 4 units):
    # its distance from the nearest camera centre is within [0.5, 4 * sqrt(2)] units (corners of the image).
    centres = np.array([f["transform_matrix"] for f in json.loads((out / "cameras.json").read_text())["frames"]])
    distances = np.linalg.norm(cloud.vertices[:, None] - centres[None, :, :3, 3], axis=-1).min(axis=1)
    assert distances.min() >= 0.5 * unit * 0.999 and distances.max() <= 4.0 * unit * 1.5


def test_no_valid_depth_gives_an_empty_cloud_that_still_loads(tmp_path):
    import imageio.v3 as iio

    from insertnerf_cli.exporters.outputs import frame_paths, write_frame
    from insertnerf_cli.exporters.pointcloud import write_pointcloud

    paths = frame_paths(tmp_path, 0)
    write_frame(paths, np.zeros((6, 8, 3)), np.zeros((6, 8), np.uint16), np.zeros((6, 8, 3), np.uint8))
    assert iio.imread(paths.depth).max() == 0
    camera = Cameras(intrinsics(10.0, 10.0, 4.0, 3.0)[None], torch.eye(4, dtype=torch.float64)[None], 6, 8)
    assert write_pointcloud(tmp_path / "cloud.ply", camera, [paths], 1e-3) == 0
    loaded = trimesh.load(tmp_path / "cloud.ply")
    assert len(getattr(loaded, "vertices", [])) == 0
