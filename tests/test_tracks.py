"""Tracks of pairwise matches triangulated at known poses: analytic cameras and points."""
from __future__ import annotations

import numpy as np
import torch

from insertnerf_cli.sfm.epipolar import ViewFeatures
from insertnerf_cli.sfm.tracks import MAX_REPROJECTION_ERROR, triangulate_tracks

FOCAL = 300.0


def _views(xyz: np.ndarray, centres: list[list[float]], order_seed: int = 0) -> tuple[list[ViewFeatures], list[np.ndarray]]:
    """(views looking down +z from ``centres``, each keypoint list shuffled; per view, [P] which keypoint shows each
    point)."""
    rng = np.random.default_rng(order_seed)
    views, where = [], []
    for centre in centres:
        pose = np.concatenate([np.eye(3), -np.asarray(centre, dtype=float)[:, None]], axis=1)
        local = xyz @ pose[:, :3].T + pose[:, 3]
        order = rng.permutation(len(xyz))
        rays = (local / local[:, 2:])[order]
        views.append(ViewFeatures(rays, torch.zeros(len(xyz), 128), pose, FOCAL))
        where.append(np.argsort(order))
    return views, where


def _all_pairs(where: list[np.ndarray], points: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
    return {(a, b): np.stack([where[a][points], where[b][points]], axis=1)
            for a in range(len(where)) for b in range(a + 1, len(where))}


def _scene(count: int = 40):
    rng = np.random.default_rng(1)
    xyz = np.concatenate([rng.uniform(-1, 1, (count, 2)), rng.uniform(4, 6, (count, 1))], axis=1)
    return xyz, *_views(xyz, [[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0], [0.5, 0.5, 0.2]])


def test_exact_matches_give_the_points_and_every_observation() -> None:
    xyz, views, where = _scene()
    tracks = triangulate_tracks(views, _all_pairs(where, np.arange(len(xyz))))
    assert len(tracks.xyz) == len(xyz)
    np.testing.assert_allclose(np.sort(tracks.xyz, axis=0), np.sort(xyz, axis=0), atol=1e-9)
    assert all(len(seen) == len(xyz) for seen in tracks.observed)


def test_a_chain_of_matches_is_one_track() -> None:
    """View 0 matched only to 1, 1 to 2, 2 to 3: each point is still one track seen by all four."""
    xyz, views, where = _scene()
    everything = np.arange(len(xyz))
    chain = {(v, v + 1): np.stack([where[v][everything], where[v + 1][everything]], axis=1) for v in range(3)}
    tracks = triangulate_tracks(views, chain)
    assert len(tracks.xyz) == len(xyz) and all(len(seen) == len(xyz) for seen in tracks.observed)


def test_an_observation_off_its_point_leaves_the_track_and_the_rest_stays() -> None:
    xyz, views, where = _scene()
    moved = views[3].rays.copy()
    keypoint = where[3][0]
    moved[keypoint, 0] += 5 * MAX_REPROJECTION_ERROR / FOCAL  # 20 px off
    views[3] = ViewFeatures(moved, views[3].descriptors, views[3].cam_from_world, FOCAL)
    tracks = triangulate_tracks(views, _all_pairs(where, np.arange(len(xyz))))
    assert len(tracks.xyz) == len(xyz)
    assert len(tracks.observed[3]) == len(xyz) - 1 and all(len(tracks.observed[v]) == len(xyz) for v in range(3))
    point = int(np.argmin(np.linalg.norm(tracks.xyz - xyz[0], axis=1)))
    np.testing.assert_allclose(tracks.xyz[point], xyz[0], atol=1e-9)  # solved again from the three that agree
    assert point not in tracks.observed[3]


def test_a_match_that_would_put_two_keypoints_of_a_view_into_one_track_is_skipped() -> None:
    xyz, views, where = _scene()
    pairs = _all_pairs(where, np.arange(len(xyz)))
    wrong = np.array([[where[0][0], where[1][1]]])  # point 0 in view 0 matched to point 1 in view 1: one track
    pairs[(0, 1)] = np.concatenate([pairs[(0, 1)], wrong])
    tracks = triangulate_tracks(views, pairs)
    assert len(tracks.xyz) == len(xyz) and all(len(seen) == len(xyz) for seen in tracks.observed)
    np.testing.assert_allclose(np.sort(tracks.xyz, axis=0), np.sort(xyz, axis=0), atol=1e-9)


def test_points_seen_from_nearly_one_place_are_dropped() -> None:
    rng = np.random.default_rng(2)
    xyz = np.concatenate([rng.uniform(-1, 1, (20, 2)), np.full((20, 1), 5.0)], axis=1)
    views, where = _views(xyz, [[0, 0, 0], [0.05, 0, 0]])  # 0.6 degrees apart at 5 units
    assert len(triangulate_tracks(views, _all_pairs(where, np.arange(20))).xyz) == 0
    views, where = _views(xyz, [[0, 0, 0], [0.3, 0, 0]])  # 3.4 degrees
    assert len(triangulate_tracks(views, _all_pairs(where, np.arange(20))).xyz) == 20


def test_no_matches_no_points() -> None:
    xyz, views, _ = _scene()
    tracks = triangulate_tracks(views, {(0, 1): np.zeros((0, 2), dtype=np.int64)})
    assert tracks.xyz.shape == (0, 3) and [len(seen) for seen in tracks.observed] == [0, 0, 0, 0]


def test_a_track_sheds_several_outliers_one_at_a_time_and_keeps_the_views_that_agree() -> None:
    """Point 0 lies 30, 40 and 50 px off in three of eight views: those three leave its track, the other five stay
    and the point is solved from them alone."""
    rng = np.random.default_rng(2)
    xyz = np.concatenate([rng.uniform(-1, 1, (20, 2)), rng.uniform(4, 6, (20, 1))], axis=1)
    centres = [[0.3 * (i % 4), 0.3 * (i // 4), 0.05 * i] for i in range(8)]
    views, where = _views(xyz, centres)
    for view, pixels in ((2, 30), (5, 40), (7, 50)):
        moved = views[view].rays.copy()
        moved[where[view][0], 1] += pixels / FOCAL
        views[view] = ViewFeatures(moved, views[view].descriptors, views[view].cam_from_world, FOCAL)
    tracks = triangulate_tracks(views, _all_pairs(where, np.arange(len(xyz))))
    point = int(np.argmin(np.linalg.norm(tracks.xyz - xyz[0], axis=1)))
    np.testing.assert_allclose(tracks.xyz[point], xyz[0], atol=1e-9)
    assert [point in tracks.observed[v] for v in range(8)] == [True, True, False, True, True, False, True, False]
