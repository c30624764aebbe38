"""The camera type: analytic projections, round trips, and the axis conversions."""
from __future__ import annotations

import math

import pytest
import torch

from insertnerf_cli.cameras.camera import (Cameras, check_shape, intrinsics, llff_to_opencv, opengl_to_opencv,
                                           w2c_to_c2w)
from scene_fixtures import opencv_to_llff, ring_cameras


def random_rotations(n: int, generator: torch.Generator) -> torch.Tensor:
    """n proper rotations [n, 3, 3] from QR of Gaussian matrices."""
    q, r = torch.linalg.qr(torch.randn(n, 3, 3, generator=generator, dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r, dim1=-2, dim2=-1))[:, None, :]
    return q * torch.det(q)[:, None, None]


def random_cameras(n: int = 4, seed: int = 0) -> Cameras:
    g = torch.Generator().manual_seed(seed)
    c2w = torch.eye(4, dtype=torch.float64).repeat(n, 1, 1)
    c2w[:, :3, :3] = random_rotations(n, g)
    c2w[:, :3, 3] = torch.randn(n, 3, generator=g, dtype=torch.float64)
    K = torch.stack([intrinsics(50 + i, 55 - i, 31.5 + i, 20.25) for i in range(n)])
    return Cameras(K, c2w, 40, 64)


def test_project_known_point() -> None:
    cams = Cameras(intrinsics(100.0, 80.0, 32.0, 24.0)[None], torch.eye(4, dtype=torch.float64)[None], 48, 64)
    uv, depth = cams.project(torch.tensor([[0.5, -0.25, 2.0]], dtype=torch.float64))
    torch.testing.assert_close(uv[0, 0], torch.tensor([32.0 + 100 * 0.25, 24.0 - 80 * 0.125], dtype=torch.float64))
    assert float(depth[0, 0]) == 2.0


def test_project_unproject_round_trip() -> None:
    cams = random_cameras()
    g = torch.Generator().manual_seed(1)
    uv = torch.rand(len(cams), 50, 2, generator=g, dtype=torch.float64) * torch.tensor([64.0, 40.0])
    depth = torch.rand(len(cams), 50, generator=g, dtype=torch.float64) * 5 + 0.1
    uv2, depth2 = cams.project(cams.unproject(uv, depth))
    torch.testing.assert_close(uv2, uv)
    torch.testing.assert_close(depth2, depth)


def test_ray_directions_have_unit_camera_depth() -> None:
    cams = random_cameras()
    uv = torch.rand(len(cams), 10, 2, dtype=torch.float64) * 30
    points = cams.centers[:, None] + 3.0 * cams.ray_directions(uv)
    uv2, depth = cams.project(points)
    torch.testing.assert_close(depth, torch.full_like(depth, 3.0))
    torch.testing.assert_close(uv2, uv)


def test_principal_point_ray_is_the_optical_axis() -> None:
    cams = random_cameras()
    centre = cams.K[:, :2, 2][:, None]  # [N, 1, 2]
    torch.testing.assert_close(cams.ray_directions(centre)[:, 0], cams.forward)


def test_opengl_opencv_twice_is_identity_and_keeps_the_pose() -> None:
    c2w = random_cameras().c2w
    torch.testing.assert_close(opengl_to_opencv(opengl_to_opencv(c2w)), c2w)
    gl = opengl_to_opencv(c2w)
    # Same centre; OpenGL looks down -z, OpenCV down +z; OpenGL y is up, OpenCV y is down.
    torch.testing.assert_close(gl[:, :3, 3], c2w[:, :3, 3])
    torch.testing.assert_close(-gl[:, :3, 2], c2w[:, :3, 2])
    torch.testing.assert_close(-gl[:, :3, 1], c2w[:, :3, 1])
    cams = random_cameras()
    torch.testing.assert_close(Cameras.from_opengl(cams.K, cams.c2w_opengl, 40, 64).c2w, cams.c2w)


def test_llff_round_trip_and_axes() -> None:
    c2w = random_cameras().c2w
    llff = opencv_to_llff(c2w)
    torch.testing.assert_close(llff_to_opencv(llff), c2w)
    # LLFF columns are [down, right, back]: OpenCV y, x, -z.
    torch.testing.assert_close(llff[:, :, 0], c2w[:, :3, 1])
    torch.testing.assert_close(llff[:, :, 1], c2w[:, :3, 0])
    torch.testing.assert_close(llff[:, :, 2], -c2w[:, :3, 2])


def test_w2c_inverse_twice_is_identity() -> None:
    cams = random_cameras()
    torch.testing.assert_close(w2c_to_c2w(cams.w2c), cams.c2w)
    torch.testing.assert_close(cams.w2c @ cams.c2w, torch.eye(4, dtype=torch.float64).expand(len(cams), 4, 4))


def test_rescale_keeps_projection_in_relative_units() -> None:
    cams = random_cameras()
    half = cams.rescale(20, 32)
    points = cams.unproject(torch.full((len(cams), 3, 2), 10.0, dtype=torch.float64),
                            torch.ones(len(cams), 3, dtype=torch.float64))
    uv, _ = cams.project(points)
    uv_half, _ = half.project(points)
    torch.testing.assert_close(uv_half, uv * 0.5)
    assert (half.height, half.width) == (20, 32)


def test_subset_cat_and_transform() -> None:
    cams = random_cameras(5)
    sub = cams.subset([3, 1])
    torch.testing.assert_close(sub.c2w, cams.c2w[[3, 1]])
    torch.testing.assert_close(Cameras.cat([cams[0:2], cams[2:5]]).c2w, cams.c2w)
    with pytest.raises(ValueError):
        Cameras.cat([cams, cams.rescale(10, 16)])
    R = random_rotations(1, torch.Generator().manual_seed(3))[0]
    t = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)
    moved = cams.transform(R, t, 2.5)
    point = torch.tensor([[0.3, 0.2, -0.1]], dtype=torch.float64)
    uv, depth = cams.project(point)
    uv2, depth2 = moved.project(2.5 * point @ R.T + t)  # a similarity keeps pixels, scales depth
    torch.testing.assert_close(uv2, uv)
    torch.testing.assert_close(depth2, 2.5 * depth)


def test_bad_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="c2w must have shape"):
        Cameras(torch.eye(3).repeat(2, 1, 1), torch.eye(4).repeat(3, 1, 1), 4, 4)
    with pytest.raises(ValueError):
        check_shape("x", torch.zeros(2, 3), (2, 4))


def test_ring_fixture_looks_at_the_origin() -> None:
    cams = ring_cameras(6)
    uv, depth = cams.project(torch.zeros(1, 3, dtype=torch.float64))
    torch.testing.assert_close(uv[:, 0], cams.K[:, :2, 2])
    torch.testing.assert_close(depth[:, 0], torch.full((6,), 4.0, dtype=torch.float64))
    assert math.isclose(float(torch.det(cams.c2w[0, :3, :3])), 1.0)
