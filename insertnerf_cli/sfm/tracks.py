"""3D points from pairwise matches at known poses: matches joined into tracks, each track triangulated by the linear
(DLT) solution over all its views, and the observations that do not reproject dropped.

At fixed poses this is what COLMAP's point triangulator does (each point refined on its reprojection error, as its
bundle adjustment does with the poses fixed), less its completion and merging of tracks: 5.5 s where COLMAP's took
22 s for 60 photos of 1000 px (docs/research-log.md, Poses and triangulation).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from insertnerf_cli.sfm.epipolar import ViewFeatures

# An observation whose reprojection lies farther than this from its keypoint leaves the track (COLMAP's
# filter_max_reproj_error).
MAX_REPROJECTION_ERROR = 4.0
# A track whose rays meet at a smaller angle places its point too loosely in depth (COLMAP's min_tri_angle).
MIN_TRIANGULATION_ANGLE = math.radians(1.5)
# Gauss-Newton steps on each point's reprojection error after its linear solution.
REFINE_STEPS = 3


@dataclass(frozen=True)
class Tracks:
    """P triangulated points and who sees them.

    xyz: [P, 3] float64 world positions.
    observed: per view, [K_v] int64 the indices of the points the view observes.
    """

    xyz: np.ndarray
    observed: tuple[np.ndarray, ...]


def triangulate_tracks(views: Sequence[ViewFeatures], matches: dict[tuple[int, int], np.ndarray],
                       max_error: float = MAX_REPROJECTION_ERROR,
                       min_angle: float = MIN_TRIANGULATION_ANGLE) -> Tracks:
    """The points of ``matches`` ((view a, view b) -> [M, 2] keypoint indices of a and b) at the poses of ``views``
    (their keypoints' rays, poses and focal lengths).

    A track is a connected set of matched keypoints, never two of one view (_tracks). Each is solved, then its
    worst observation dropped and the track solved again for as long as that one lies farther than ``max_error``
    px (or behind its camera); it is kept if at least two views remain and their rays meet at ``min_angle`` or
    more. Dropping one at a time keeps the good observations of a track with several outliers, which a cut of
    every observation past ``max_error`` around a point they pulled aside would lose."""
    offsets = np.cumsum([0] + [len(v.rays) for v in views])
    view_of = np.repeat(np.arange(len(views)), np.diff(offsets))
    listed = [(offsets[a] + m[:, 0], offsets[b] + m[:, 1]) for (a, b), m in matches.items() if len(m)]
    if not listed:
        return _empty(len(views))
    first, second = np.concatenate([f for f, _ in listed]), np.concatenate([s for _, s in listed])
    label = _tracks(first, second, view_of)
    nodes = np.flatnonzero(np.bincount(label, minlength=len(label))[label] >= 2)  # keypoints in some track
    if not len(nodes):
        return _empty(len(views))
    track = np.unique(label[nodes], return_inverse=True)[1]
    rays = np.concatenate([v.rays for v in views])[nodes]
    pose = np.stack([v.cam_from_world for v in views])[view_of[nodes]]
    focal = np.array([v.focal for v in views])[view_of[nodes]]
    keep = np.ones(len(nodes), dtype=bool)
    tracks = int(track.max()) + 1
    xyz, error = np.full((tracks, 3), np.inf), np.full(len(nodes), np.inf)
    changed = np.ones(tracks, dtype=bool)  # the tracks whose observations changed since they were last solved
    while True:
        keep &= _kept_per_track(track, keep, tracks)[track] >= 2
        in_changed = changed[track]  # [n] only these observations' points and errors can have moved
        xyz[changed] = _solved_points(track, keep & in_changed, changed, rays, pose, focal)
        rows = np.flatnonzero(in_changed)
        error[rows] = _reprojection_error(xyz[track[rows]], rays[rows], pose[rows], focal[rows])
        # One outlier pulls its track's point off the others too: drop only each track's worst, then solve again,
        # until no track holds an observation past max_error (a track left with one is dropped above).
        live = rows[keep[rows]]
        worst = np.full(tracks, -1.0)
        np.maximum.at(worst, track[live], error[live])
        dropped = live[(error[live] == worst[track[live]]) & (error[live] > max_error)]
        if not len(dropped):
            break
        keep[dropped] = False
        changed = np.zeros(tracks, dtype=bool)
        changed[track[dropped]] = True
    good = np.isfinite(xyz).all(axis=1) & (_kept_per_track(track, keep, tracks) >= 2)
    good &= _spread(xyz, track, keep, pose, len(xyz)) >= min_angle
    keep &= good[track]
    index = np.full(len(xyz), -1)
    index[good] = np.arange(int(good.sum()))
    seen_view, seen_point = view_of[nodes[keep]], index[track[keep]]
    observed = tuple(np.sort(seen_point[seen_view == v]) for v in range(len(views)))
    return Tracks(xyz[good], observed)


def _solved_points(track: np.ndarray, rows: np.ndarray, which: np.ndarray, rays: np.ndarray, pose: np.ndarray,
                   focal: np.ndarray) -> np.ndarray:
    """[W, 3] the refined DLT points of the W tracks ``which`` [T] (bool) marks, from their observations ``rows``
    [n] (bool) marks."""
    local = np.cumsum(which) - 1  # [T] a marked track's place among the marked
    labels = local[track[rows]]
    return _refine(_solve(rays[rows], pose[rows], labels, int(which.sum())), rays[rows], pose[rows], focal[rows],
                   labels)


def _empty(views: int) -> Tracks:
    return Tracks(np.zeros((0, 3)), tuple(np.zeros(0, dtype=np.int64) for _ in range(views)))


def _tracks(first: np.ndarray, second: np.ndarray, view_of: np.ndarray) -> np.ndarray:
    """[nodes] each keypoint's track: the matches ``first`` [M] - ``second`` [M] (global keypoint indices) joined,
    except that a match which would put two keypoints of one view into a track is skipped (one of the track's
    matches is wrong; COLMAP's track building does the same). Most matches join without such a conflict and are
    joined all at once; only the components that hold a conflict are built again match by match, in order."""
    label = _components(first, second, len(view_of))
    key = label * (int(view_of.max()) + 1) + view_of
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    conflicted = np.zeros(len(label), dtype=bool)
    conflicted[label[counts[inverse] > 1]] = True  # the roots of components holding a view twice
    redo = conflicted[label[first]]
    if redo.any():
        nodes = np.flatnonzero(conflicted[label])
        label[nodes] = nodes
        label = _join_without_conflicts(label, first[redo], second[redo], view_of)
    return label


def _components(first: np.ndarray, second: np.ndarray, count: int) -> np.ndarray:
    """[count] each node's component: the smallest node index it connects to (min-label propagation with pointer
    jumping; tracks are short, so a few rounds suffice)."""
    label = np.arange(count)
    while True:
        low = np.minimum(label[first], label[second])
        before = label.copy()
        np.minimum.at(label, first, low)
        np.minimum.at(label, second, low)
        label = label[label]  # jump: a node takes its label's label
        if np.array_equal(label, before):
            return label


def _join_without_conflicts(label: np.ndarray, first: np.ndarray, second: np.ndarray, view_of: np.ndarray) -> np.ndarray:
    """``label`` with the matches ``first`` - ``second`` joined in order by union-find, each root carrying the set
    of its views as bits, a match skipped where both sides already hold a common view."""
    parent = label.tolist()
    views = {int(n): 1 << int(view_of[n]) for n in np.unique(np.concatenate([first, second]))}

    def root(node: int) -> int:
        top = node
        while parent[top] != top:
            top = parent[top]
        while parent[node] != top:
            parent[node], node = top, parent[node]
        return top

    for a, b in zip(first.tolist(), second.tolist()):
        ra, rb = root(a), root(b)
        if ra != rb and not views[ra] & views[rb]:
            low, high = min(ra, rb), max(ra, rb)
            parent[high] = low
            views[low] |= views[high]
    return np.array([root(n) for n in range(len(parent))])


def _kept_per_track(track: np.ndarray, keep: np.ndarray, tracks: int) -> np.ndarray:
    """[tracks] how many kept observations each track holds."""
    return np.bincount(track[keep], minlength=tracks)


def _solve(rays: np.ndarray, pose: np.ndarray, track: np.ndarray, tracks: int) -> np.ndarray:
    """[tracks, 3] each track's DLT point (inf where it has fewer than two observations or lies at infinity): the
    null vector of the stacked rows x P3 - P1, y P3 - P2, through the smallest eigenvector of their normal matrix."""
    x_rows = rays[:, 0:1] * pose[:, 2] - pose[:, 0]  # [n, 4]
    y_rows = rays[:, 1:2] * pose[:, 2] - pose[:, 1]
    normal = torch.zeros(tracks, 4, 4, dtype=torch.float64)
    for rows in (torch.from_numpy(x_rows), torch.from_numpy(y_rows)):
        normal.index_add_(0, torch.from_numpy(track), rows[:, :, None] * rows[:, None, :])
    count = np.bincount(track, minlength=tracks)
    normal[torch.from_numpy(count < 2)] = torch.eye(4, dtype=torch.float64)  # solvable; marked below
    _, vectors = torch.linalg.eigh(normal)
    point = vectors[:, :, 0].numpy()  # [tracks, 4] homogeneous
    with np.errstate(divide="ignore", invalid="ignore"):
        xyz = point[:, :3] / point[:, 3:]
    xyz[(count < 2) | (np.abs(point[:, 3]) < 1e-12)] = np.inf
    return xyz


def _refine(xyz: np.ndarray, rays: np.ndarray, pose: np.ndarray, focal: np.ndarray, track: np.ndarray,
            iterations: int = REFINE_STEPS) -> np.ndarray:
    """[tracks, 3] the DLT points moved by Gauss-Newton steps to minimise their observations' reprojection error in
    pixels (the DLT minimises an algebraic error, which weighs the views unevenly; COLMAP refines the same way)."""
    xyz = xyz.copy()
    solvable = np.isfinite(xyz).all(axis=1)
    use = solvable[track]
    rays, pose, focal, track = rays[use], pose[use], focal[use], track[use]
    index = torch.from_numpy(track)
    for _ in range(iterations):
        camera = np.einsum("nij,nj->ni", pose[:, :, :3], xyz[track]) + pose[:, :, 3]  # [n, 3]
        depth = np.where(np.abs(camera[:, 2]) > 1e-12, camera[:, 2], 1e-12)
        projected = camera[:, :2] / depth[:, None]
        residual = focal[:, None] * (projected - rays[:, :2])  # [n, 2] px
        # d(projected)/dX = (R[:2] - projected R[2]) / z
        jacobian = focal[:, None, None] * (pose[:, :2, :3] - projected[:, :, None] * pose[:, 2:3, :3]) \
            / depth[:, None, None]  # [n, 2, 3]
        j = torch.from_numpy(jacobian)
        normal = torch.zeros(len(xyz), 3, 3, dtype=torch.float64).index_add_(0, index, j.transpose(1, 2) @ j)
        gradient = torch.zeros(len(xyz), 3, dtype=torch.float64).index_add_(
            0, index, (j.transpose(1, 2) @ torch.from_numpy(residual)[:, :, None])[:, :, 0])
        normal[~torch.from_numpy(solvable)] = torch.eye(3, dtype=torch.float64)
        damping = 1e-9 * normal.diagonal(dim1=1, dim2=2).sum(dim=1).clamp_min(1e-12)
        step = torch.linalg.solve(normal + damping[:, None, None] * torch.eye(3, dtype=torch.float64), gradient)
        xyz[solvable] -= step.numpy()[solvable]
    return xyz


def _reprojection_error(xyz: np.ndarray, rays: np.ndarray, pose: np.ndarray, focal: np.ndarray) -> np.ndarray:
    """[n] each observation's reprojection error in px; inf where its point is unsolved or behind the camera."""
    with np.errstate(invalid="ignore", divide="ignore"):
        camera = np.einsum("nij,nj->ni", pose[:, :, :3], xyz) + pose[:, :, 3]
        error = focal * np.linalg.norm(camera[:, :2] / camera[:, 2:] - rays[:, :2], axis=1)
    return np.where(np.isfinite(error) & (camera[:, 2] > 0), error, np.inf)


def _spread(xyz: np.ndarray, track: np.ndarray, keep: np.ndarray, pose: np.ndarray, tracks: int) -> np.ndarray:
    """[tracks] twice the largest angle between a kept observation's ray to the point and the rays' mean: for two
    views exactly the angle at which they meet, for more a lower bound of the widest pair's."""
    with np.errstate(invalid="ignore", divide="ignore"):  # inf points (unsolved tracks) come out nan: not kept
        return _spread_finite(xyz, track, keep, pose, tracks)


def _spread_finite(xyz: np.ndarray, track: np.ndarray, keep: np.ndarray, pose: np.ndarray, tracks: int) -> np.ndarray:
    rotation, translation = pose[keep, :, :3], pose[keep, :, 3]
    centre = -np.einsum("nji,nj->ni", rotation, translation)  # camera centres in the world
    ray = xyz[track[keep]] - centre
    ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-300)
    mean = np.zeros((tracks, 3))
    np.add.at(mean, track[keep], ray)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
    angle = np.arccos(np.clip((ray * mean[track[keep]]).sum(axis=1), -1.0, 1.0))
    widest = np.zeros(tracks)
    np.maximum.at(widest, track[keep], angle)
    return 2.0 * widest
