"""SIFT matches between views of known pose, searched along each keypoint's epipolar line (triangulate).

COLMAP's matcher compares every keypoint with every other and keeps a match where the nearest descriptor is clearly
nearer than the second (the ratio test); RANSAC then estimates the pair's geometry from those. Where a texture
repeats (a cape's punched rows, a box of tissue, a lab's cabinets) the second-nearest descriptor is as near as the
first somewhere else in the photo, so the ratio test throws the match away, and a scene without those matches
gets no points there. A scene that `triangulate` serves has its poses already: the true match of a keypoint lies
within a few pixels of its epipolar line, so the ratio test need only beat the rivals near that line (COLMAP's
"guided matching", with the known poses in place of a geometry estimated from the first matches, and without
matching twice). On a capture of repeating texture this about doubles the points and widens the prior's cover of
a frame (measured: docs/research-log.md, Poses and triangulation). Its cost: a match on its line always
triangulates, so a wrong one is not caught. On procedural scenes a quarter of the points become two-view tracks
(3 % with COLMAP's matcher); their depth error falls, but the fast generator's PSNR on them falls a little.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from insertnerf_cli.poses.check import skew

# A keypoint's rivals are those within this many pixels of its epipolar line (COLMAP's RANSAC error for
# two-view geometry, whose guided matching uses the same band).
MAX_EPIPOLAR_ERROR = 4.0
# COLMAP's SIFT matching defaults: the nearest descriptor's angle at most MAX_RATIO times the second nearest's,
# and at most MAX_DISTANCE radians.
MAX_RATIO = 0.8
MAX_DISTANCE = 0.7
# Keypoints whose epipolar lines are tested at once. Taken in the order of their lines' angles, a block's lines
# lie side by side, so that the other view's keypoints near any of them are a small share, and only those are
# compared by descriptor (the same matches as blocks in file order, about 2x faster, the more so the more
# keypoints a photo has: docs/research-log.md, Speed).
ROWS_PER_BLOCK = 512


@dataclass(frozen=True)
class ViewFeatures:
    """One view's SIFT features and pose, in the terms the epipolar test needs.

    rays: [N, 3] float64 each keypoint's direction in the camera (x, y, 1): the lens's distortion removed.
    descriptors: [N, 128] float32, unit length.
    cam_from_world: [3, 4] float64 the view's pose (COLMAP's, world to camera).
    focal: pixels per unit of ``rays``' x and y (the mean of fx and fy), to state the band in pixels.
    """

    rays: np.ndarray
    descriptors: torch.Tensor
    cam_from_world: np.ndarray
    focal: float

    @staticmethod
    def of_photo(camera, keypoints: np.ndarray, descriptors: np.ndarray, cam_from_world: np.ndarray) -> "ViewFeatures":
        """The ViewFeatures of a pycolmap ``camera`` (the photo's own, lens distortion included) from its
        ``keypoints`` [N, 2] (pixel x, y, COLMAP's convention, as the camera reads them), SIFT ``descriptors``
        [N, 128] and ``cam_from_world`` [3, 4]."""
        xy = camera.cam_from_img(np.ascontiguousarray(keypoints[:, :2], dtype=np.float64)) if len(keypoints) else \
            np.zeros((0, 2))
        rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        table = torch.from_numpy(np.asarray(descriptors, dtype=np.float32))
        table = table / table.norm(dim=1, keepdim=True).clamp_min(1e-12)
        focal = 0.5 * (camera.focal_length_x + camera.focal_length_y)
        return ViewFeatures(rays, table, np.asarray(cam_from_world, dtype=np.float64), float(focal))


def _b_from_a(a: ViewFeatures, b: ViewFeatures) -> tuple[np.ndarray, np.ndarray]:
    """([3, 3] rotation, [3] translation) of b's camera from a's."""
    rotation = b.cam_from_world[:, :3] @ a.cam_from_world[:, :3].T
    return rotation, b.cam_from_world[:, 3] - rotation @ a.cam_from_world[:, 3]


def essential_matrix(a: ViewFeatures, b: ViewFeatures) -> np.ndarray:
    """[3, 3] E with rays_b^T E rays_a = 0 for a point seen by both views."""
    rotation, translation = _b_from_a(a, b)
    return skew(translation) @ rotation


def epipolar_matches(a: ViewFeatures, b: ViewFeatures, max_error: float = MAX_EPIPOLAR_ERROR,
                     max_ratio: float = MAX_RATIO, max_distance: float = MAX_DISTANCE) -> np.ndarray:
    """[M, 2] int (keypoint of a, keypoint of b): pairs that lie within ``max_error`` px of each other's epipolar
    line, whose descriptors pass the ratio test against every rival within that band, both ways (a mutual best)."""
    e = essential_matrix(a, b)
    if len(a.rays) < 2 or len(b.rays) < 2 or not np.any(e):
        return np.zeros((0, 2), dtype=np.int64)  # a view with no baseline to the other has no epipolar line
    # Normalised coordinates stay within a few units, so float32 residuals err by far less than a pixel.
    rays_a, rays_b = torch.from_numpy(a.rays).float(), torch.from_numpy(b.rays).float()
    lines_b = rays_a @ torch.from_numpy(e.T).float()  # [Na, 3] each a-keypoint's line in b
    lines_a = rays_b @ torch.from_numpy(e).float()  # [Nb, 3] each b-keypoint's line in a
    # |x_b . l_b| is both keypoints' residual; in pixels it is that over |l[:2]| times the view's focal length.
    band_b = max_error * lines_b[:, :2].norm(dim=1) / b.focal  # [Na] the residual allowed, measured in b
    band_a = max_error * lines_a[:, :2].norm(dim=1) / a.focal  # [Nb] measured in a
    # The float32 residuals below may pass a hair over the float64 bound: the pencil's reach is a little wider.
    first, second, similarity = _pairs_in_band(lines_b, rays_b, band_b, band_a, a.descriptors, b.descriptors,
                                               _Pencil.about(epipole_in_b(a, b)), 1.001 * max_error / b.focal, b.rays)
    forward = _best_of(first, second, similarity, len(rays_a), max_ratio, max_distance)
    backward = _best_of(second, first, similarity, len(rays_b), max_ratio, max_distance)
    rows = torch.nonzero(forward >= 0).flatten()
    mutual = rows[backward[forward[rows]] == rows]
    return torch.stack([mutual, forward[mutual]], dim=1).numpy().astype(np.int64)


def epipole_in_b(a: ViewFeatures, b: ViewFeatures) -> np.ndarray:
    """[3] the epipole in b (a's centre seen from b, as a ray; unit length): every line of a's keypoints passes
    through it."""
    _, translation = _b_from_a(a, b)
    return translation / np.linalg.norm(translation)


@dataclass(frozen=True)
class _Pencil:
    """The lines through an epipole e as one angle: a line l (l . e = 0) has phi = atan2(l . u2, l . u1) mod pi for
    an orthonormal u1, u2 perpendicular to e. A unit line at angle phi_x + d from the line through e and a ray x
    leaves x a residual |sin d| |n . x| (n: the unit line at phi_x + pi/2), so a keypoint whose residual against
    lines at angle distance d is within r needs |sin d| <= r / |n . x|: a test on two numbers per keypoint."""

    u1: np.ndarray
    u2: np.ndarray
    epipole: np.ndarray

    @staticmethod
    def about(epipole: np.ndarray) -> "_Pencil":
        helper = np.eye(3)[int(np.argmin(np.abs(epipole)))]
        u1 = np.cross(epipole, helper)
        u1 /= np.linalg.norm(u1)
        return _Pencil(u1, np.cross(epipole, u1), epipole)

    def angle(self, lines: np.ndarray) -> np.ndarray:
        """[N] float64 each line's angle in [0, pi)."""
        return np.remainder(np.arctan2(lines @ self.u2, lines @ self.u1), math.pi)

    def reach(self, rays: np.ndarray, residual: float) -> tuple[np.ndarray, np.ndarray]:
        """([N] angle of the line through each ray, [N] how far in angle a line may lie with the ray's residual
        against it within ``residual`` (pi / 2: any line))."""
        through = np.cross(self.epipole[None, :], rays)
        phi = self.angle(through)
        normal = -np.sin(phi)[:, None] * self.u1 + np.cos(phi)[:, None] * self.u2
        lever = np.abs((rays * normal).sum(axis=1))
        with np.errstate(divide="ignore"):
            reach = np.arcsin(np.minimum(1.0, residual / lever))
        return phi, reach


def _pairs_in_band(lines: torch.Tensor, rays: torch.Tensor, band: torch.Tensor, other_band: torch.Tensor,
                   descriptors: torch.Tensor, other: torch.Tensor, pencil: _Pencil, residual: float,
                   rays64: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """([K], [K], [K]) every (a-keypoint, b-keypoint) whose residual against the a-keypoints' ``lines`` [Na, 3] in b
    (b's keypoints along ``rays`` [Nb, 3]; ``rays64`` the same in float64) is within both ``band`` [Na] and
    ``other_band`` [Nb] (a few per cent of all pairs), and the cosine of the angle between their ``descriptors``
    [Na, 128] and ``other`` [Nb, 128]. ``pencil`` and ``residual`` (the widest band, in b's normalised units)
    narrow each block of lines to the keypoints that can lie in its band before any residual is computed."""
    found_a, found_b, found = [], [], []
    phi_lines = pencil.angle(lines.double().numpy())
    order = np.argsort(phi_lines, kind="stable")
    phi_rays, reach = pencil.reach(rays64, residual)
    for start in range(0, len(lines), ROWS_PER_BLOCK):
        rows_np = order[start:start + ROWS_PER_BLOCK]
        low, high = phi_lines[rows_np[0]], phi_lines[rows_np[-1]]  # sorted: the block spans [low, high]
        outside = np.minimum(np.remainder(low - phi_rays, math.pi), np.remainder(phi_rays - high, math.pi))
        inside = (phi_rays >= low) & (phi_rays <= high)
        candidates = torch.from_numpy(np.flatnonzero(inside | (outside <= reach)))
        rows = torch.from_numpy(rows_np)
        residual_block = (lines[rows] @ rays[candidates].T).abs_()  # [n, C]
        near = (residual_block <= band[rows, None]) & (residual_block <= other_band[None, candidates])
        columns = torch.nonzero(near.any(dim=0)).flatten()
        index_a, index_b = torch.nonzero(near[:, columns], as_tuple=True)
        columns = candidates[columns]
        # A matrix product over the block's candidates beats a gather of descriptor rows per pair.
        found.append((descriptors[rows] @ other[columns].T)[index_a, index_b])
        found_a.append(rows[index_a])
        found_b.append(columns[index_b])
    return torch.cat(found_a), torch.cat(found_b), torch.cat(found)


def _best_of(index: torch.Tensor, other: torch.Tensor, similarity: torch.Tensor, count: int, max_ratio: float,
             max_distance: float) -> torch.Tensor:
    """[count] for each keypoint the ``other`` of its candidate pairs (``index`` [K], ``other`` [K], their
    ``similarity`` [K]) that passes the ratio test against its rivals (-1: none does, or two tie)."""
    none = torch.full((count,), -1.0)
    nearest = none.scatter_reduce(0, index, similarity, "amax")
    is_nearest = similarity == nearest[index]
    ties = torch.bincount(index[is_nearest], minlength=count)
    second = none.scatter_reduce(0, index, similarity.masked_fill(is_nearest, -1.0), "amax")
    angle, rival = torch.acos(nearest.clamp(-1.0, 1.0)), torch.acos(second.clamp(-1.0, 1.0))
    ok = (ties == 1) & (angle <= max_distance) & (angle < max_ratio * rival)
    best = torch.full((count,), -1, dtype=torch.long)
    best[index[is_nearest]] = other[is_nearest]
    return torch.where(ok, best, torch.full_like(best, -1))
