"""SIFT matches searched along the epipolar lines of known poses: analytic cameras and points."""
from __future__ import annotations

import numpy as np
import pycolmap
import pytest

from insertnerf_cli.sfm.epipolar import MAX_EPIPOLAR_ERROR, MAX_RATIO, ViewFeatures, epipolar_matches

SIZE, FOCAL, POINTS = 400, 350.0, 60


def _camera(params_extra: list[float] | None = None) -> pycolmap.Camera:
    if params_extra is None:
        return pycolmap.Camera(model="PINHOLE", width=SIZE, height=SIZE,
                               params=[FOCAL, FOCAL, SIZE / 2, SIZE / 2])
    return pycolmap.Camera(model="OPENCV", width=SIZE, height=SIZE,
                           params=[FOCAL, FOCAL, SIZE / 2, SIZE / 2, *params_extra])


def _pose(angle_deg: float) -> np.ndarray:
    """[3, 4] cam_from_world of a camera 4 units from the origin, turned about y by ``angle_deg``, facing it."""
    a = np.radians(angle_deg)
    rotation = np.array([[np.cos(a), 0.0, -np.sin(a)], [0.0, 1.0, 0.0], [np.sin(a), 0.0, np.cos(a)]])
    return np.concatenate([rotation, np.array([[0.0], [0.0], [4.0]])], axis=1)


def _project(camera: pycolmap.Camera, pose: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    local = xyz @ pose[:, :3].T + pose[:, 3]
    return camera.img_from_cam(local)  # [N, 2] pixels, the lens's distortion applied


def _descriptors(count: int, rng: np.random.Generator) -> np.ndarray:
    """[count, 128] uint8, as SIFT stores them (non-negative, scaled to 512)."""
    raw = rng.random((count, 128)) ** 4
    return np.clip(raw / np.linalg.norm(raw, axis=1, keepdims=True) * 512, 0, 255).astype(np.uint8)


def _scene(rng: np.random.Generator, distortion: list[float] | None = None):
    """(features of view a, of view b, the true pairs [N, 2]): the same points seen 20 degrees apart, listed in
    another order in b."""
    xyz = rng.uniform(-1.0, 1.0, size=(POINTS, 3))
    camera = _camera(distortion)
    pose_a, pose_b = _pose(0.0), _pose(20.0)
    descriptors = _descriptors(POINTS, rng)
    order = rng.permutation(POINTS)  # b's keypoint k is point order[k]
    a = ViewFeatures.of_photo(camera, _project(camera, pose_a, xyz), descriptors, pose_a)
    b = ViewFeatures.of_photo(camera, _project(camera, pose_b, xyz)[order], descriptors[order], pose_b)
    truth = np.stack([order, np.arange(POINTS)], axis=1)
    return a, b, truth[np.argsort(truth[:, 0])]


@pytest.mark.parametrize("distortion", [None, [-0.2, 0.05, 0.0, 0.0]], ids=["pinhole", "radial"])
def test_every_point_is_matched_to_itself_and_to_nothing_else(distortion) -> None:
    a, b, truth = _scene(np.random.default_rng(0), distortion)
    found = epipolar_matches(a, b)
    np.testing.assert_array_equal(found[np.argsort(found[:, 0])], truth)


def test_a_twin_elsewhere_in_the_photo_does_not_spoil_the_match_but_a_twin_on_the_line_does() -> None:
    rng = np.random.default_rng(1)
    a, b, truth = _scene(rng)
    point, keypoint_b = truth[0]
    # A rival in b with the same descriptor far off point 0's epipolar line: a whole-photo ratio test would drop
    # the match (two equal nearest descriptors); along the line there is one candidate.
    far_off = b.rays[keypoint_b] + np.array([0.0, 60.0 / FOCAL, 0.0]) * np.sign(0.5 - b.rays[keypoint_b, 1])
    twin_off = _with_keypoint(b, far_off, keypoint_b)
    assert [point, keypoint_b] in epipolar_matches(a, twin_off).tolist()
    # The same rival 1 px along the line from the true keypoint: nothing tells them apart, so no match.
    line = _line_in_b(a, b, point)
    along = np.array([line[1], -line[0], 0.0]) / np.hypot(line[0], line[1])
    twin_on = _with_keypoint(b, b.rays[keypoint_b] + along / FOCAL, keypoint_b)
    assert point not in epipolar_matches(a, twin_on)[:, 0]


def test_a_keypoint_off_its_line_is_not_matched() -> None:
    a, b, truth = _scene(np.random.default_rng(2))
    point, keypoint_b = truth[0]
    line = _line_in_b(a, b, point)
    normal = np.array([line[0], line[1], 0.0]) / np.hypot(line[0], line[1])
    rays = b.rays.copy()
    rays[keypoint_b] += normal * (2.0 * MAX_EPIPOLAR_ERROR / FOCAL)
    moved = type(b)(rays, b.descriptors, b.cam_from_world, b.focal)
    found = epipolar_matches(a, moved)
    assert point not in found[:, 0] and len(found) == POINTS - 1


def test_views_from_one_centre_have_no_epipolar_line_and_no_match() -> None:
    a, _, _ = _scene(np.random.default_rng(3))
    assert epipolar_matches(a, a).shape == (0, 2)


def _line_in_b(a, b, point: int) -> np.ndarray:
    from insertnerf_cli.sfm.epipolar import essential_matrix

    return essential_matrix(a, b) @ a.rays[point]


def _with_keypoint(b, ray: np.ndarray, copy_of: int):
    """``b`` with one more keypoint along ``ray`` whose descriptor is keypoint ``copy_of``'s."""
    import torch

    return type(b)(np.concatenate([b.rays, ray[None]]), torch.cat([b.descriptors, b.descriptors[copy_of:copy_of + 1]]),
                   b.cam_from_world, b.focal)


def _brute_force(a, b) -> set[tuple[int, int]]:
    """The matches by the definition, every keypoint pair tested: both residuals within the band, the ratio test
    against every rival in the band, both ways, mutual."""
    from insertnerf_cli.sfm.epipolar import MAX_DISTANCE, essential_matrix

    e = essential_matrix(a, b)
    lines_b, lines_a = a.rays @ e.T, b.rays @ e
    residual = np.abs(lines_b @ b.rays.T)  # [Na, Nb]
    near = (residual <= MAX_EPIPOLAR_ERROR * np.linalg.norm(lines_b[:, :2], axis=1)[:, None] / b.focal) & \
        (residual <= MAX_EPIPOLAR_ERROR * np.linalg.norm(lines_a[:, :2], axis=1)[None, :] / a.focal)
    angle = np.where(near, np.arccos(np.clip(a.descriptors.numpy() @ b.descriptors.numpy().T, -1, 1)), np.inf)

    def best(table: np.ndarray) -> np.ndarray:
        order = np.sort(table, axis=1)
        pick = np.argmin(table, axis=1)
        ok = (order[:, 0] <= MAX_DISTANCE) & (order[:, 0] < MAX_RATIO * order[:, 1]) & np.isfinite(order[:, 0])
        return np.where(ok, pick, -1)

    forward, backward = best(angle), best(angle.T)
    return {(i, int(j)) for i, j in enumerate(forward) if j >= 0 and backward[j] == i}


@pytest.mark.parametrize("motion", ["sideways", "forward", "diagonal"])
def test_the_search_by_the_lines_angle_finds_exactly_the_matches_of_testing_every_pair(motion: str) -> None:
    """The block search narrows the keypoints by the angle of their line through the epipole before any residual is
    computed; with the epipole far off (sideways), inside the photo (forward) or in a corner, and many keypoints
    near every line, it must find what testing every pair finds."""
    rng = np.random.default_rng(7)
    camera = _camera()
    count = 1500
    pose_a = np.concatenate([np.eye(3), np.zeros((3, 1))], axis=1)
    step = {"sideways": [0.3, 0.0, 0.0], "forward": [0.0, 0.0, 0.4], "diagonal": [0.2, 0.15, 0.3]}[motion]
    pose_b = np.concatenate([np.eye(3), -np.array(step)[:, None]], axis=1)
    xyz = np.concatenate([rng.uniform(-2, 2, (count, 2)), rng.uniform(3, 8, (count, 1))], axis=1)
    # Few kinds of descriptor, each a little perturbed (no exact ties): a keypoint has many look-alikes, so rivals
    # inside the band decide most matches.
    palette = _descriptors(12, rng).astype(float)

    def described(count: int) -> np.ndarray:
        return palette[rng.integers(0, 12, count)] + rng.uniform(0, 12, (count, 128))

    kept_a = _inside(_project(camera, pose_a, xyz))
    kept_b = _inside(_project(camera, pose_b, xyz))
    a = ViewFeatures.of_photo(camera, _project(camera, pose_a, xyz)[kept_a], described(int(kept_a.sum())),
                              pose_a)
    jitter = rng.normal(0, 2.0, (int(kept_b.sum()), 2))
    b = ViewFeatures.of_photo(camera, _project(camera, pose_b, xyz)[kept_b] + jitter,
                              described(int(kept_b.sum())), pose_b)
    found = {tuple(m) for m in epipolar_matches(a, b).tolist()}
    assert found == _brute_force(a, b)
    assert len(found) >= 10


def _inside(pixels: np.ndarray) -> np.ndarray:
    return np.all((pixels >= 0) & (pixels < SIZE), axis=1)
