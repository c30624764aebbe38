"""A check of SfM poses that does not trust the reprojection error.

A bundle adjustment can reach a sub-pixel reprojection error on a wrong trajectory: with repeated texture,
wrong matches between look-alike surfaces are made consistent by folding the trajectory (reproduced in
bench/poses_trap.py: 24/24 registered at 0.31 px, cameras 23 deg off). Comparing relative rotations alone does
not see it: most pairs of views stay consistent with each other while the loop is torn in one or two places.

What does see it: for every image pair with enough matches, an independent two-view estimate (OpenCV's five-point
essential matrix with USAC, on the raw descriptor matches rather than COLMAP's verified inliers) says how many of
the pair's matches one rigid motion explains. The reconstruction's relative pose of the same two cameras must
explain about as many; a pair where it explains fewer than half is *contradicted*.

Which contradictions matter: repeated texture also produces wrong matches between different surfaces, and a
*correct* model contradicts those pairs. Such wrong matches lie on the repeated (flat) pattern, so COLMAP
classifies the pair as planar. A torn trajectory instead contradicts well-matched general (non-planar) pairs,
typically neighbouring views with hundreds of matches. So the decision uses general pairs only, weighted by
their match counts; contradicted planar pairs are reported as a hint of repeated texture.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

# Pairs with fewer matches than this (after OpenCV's RANSAC) give no trustworthy two-view rotation.
MIN_PAIR_INLIERS = 30


@dataclass(frozen=True)
class PairMatches:
    """Matched points of two registered images and the reconstruction's relative pose.

    Attributes:
        names: the two image names.
        points1, points2: [M, 2] matched points in normalised camera coordinates (distortion removed, z = 1).
        rotation: [3, 3] reconstruction's cam2_from_cam1 rotation.
        translation: [3] reconstruction's cam2_from_cam1 translation (any scale).
        pixel_scale: focal length in pixels, to express a pixel threshold in normalised units.
        general: False for pairs COLMAP classified as planar or pure rotation, whose essential matrix (and so
            rotation) is ambiguous; their matches still count in the contradiction measure.
    """

    names: tuple[str, str]
    points1: np.ndarray  # [M, 2]
    points2: np.ndarray  # [M, 2]
    rotation: np.ndarray  # [3, 3]
    translation: np.ndarray  # [3]
    pixel_scale: float
    general: bool = True


@dataclass(frozen=True)
class CheckLimits:
    """Thresholds of :func:`check_relative_poses`.

    Attributes:
        threshold_px: epipolar (Sampson) inlier threshold of the two-view estimate, pixels; the reconstruction
            is allowed twice as much, since one pose serves many pairs.
        max_contradicted_share: largest share of the general pairs' matches that may sit in contradicted pairs.
        max_median_deg: largest median rotation disagreement over general pairs.
    """

    threshold_px: float = 1.5
    max_contradicted_share: float = 0.05
    max_median_deg: float = 5.0


@dataclass(frozen=True)
class PoseCheck:
    """Agreement of the reconstruction with independent two-view estimates.

    Attributes:
        general_pairs, planar_pairs: pairs compared (0 + 0 = nothing to compare: inconclusive).
        contradicted_general, contradicted_planar: pairs whose matches the model explains less than half as well
            as the pair's own two-view estimate.
        contradicted_share: share of the general pairs' two-view inliers that lie in contradicted pairs.
        median_rotation_deg: median relative-rotation disagreement over general pairs (NaN if none).
        limits: the thresholds applied.
    """

    general_pairs: int
    planar_pairs: int
    contradicted_general: int
    contradicted_planar: int
    contradicted_share: float
    median_rotation_deg: float
    limits: CheckLimits

    @property
    def pairs(self) -> int:
        return self.general_pairs + self.planar_pairs

    @property
    def passed(self) -> bool:
        """True when both measures are within their limits (or nothing could be compared)."""
        rotation_ok = not self.median_rotation_deg > self.limits.max_median_deg  # NaN (no general pair) passes
        return self.contradicted_share <= self.limits.max_contradicted_share and rotation_ok

    def summary(self) -> str:
        if self.pairs == 0:
            return "no image pair had enough matches to compare (check inconclusive)"
        text = (f"{self.contradicted_general} of {self.general_pairs} general pairs contradict the poses "
                f"({100 * self.contradicted_share:.1f} % of their matches), relative rotations off by "
                f"{self.median_rotation_deg:.2f} deg median" if self.general_pairs else "no general pair to compare")
        if self.contradicted_planar:
            text += (f"; {self.contradicted_planar} of {self.planar_pairs} planar pairs too "
                     "(repeated texture matched across surfaces)")
        return text


# A pair is contradicted when the reconstruction explains fewer than this fraction of the matches its own
# two-view estimate explains (measured: 0.99-1.0 on the pairs of correct reconstructions, 0.0-0.06 on the torn
# pairs of the repeated-texture trap).
EXPLAINED_FRACTION = 0.5


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """Angle in degrees of a rotation matrix [3, 3]."""
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0))))


def skew(v: np.ndarray) -> np.ndarray:
    """[3, 3] the matrix of the cross product with ``v`` [3]: skew(v) @ x == np.cross(v, x)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def sampson_distance(E: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """First-order geometric distance [M] of matches x1, x2 [M, 2] (normalised coordinates) to E [3, 3]."""
    X1 = np.column_stack([x1, np.ones(len(x1))])
    X2 = np.column_stack([x2, np.ones(len(x2))])
    Ex1, Etx2 = X1 @ E.T, X2 @ E  # [M, 3] epipolar lines in image 2 and image 1
    residual = np.sum(X2 * Ex1, axis=1)
    norm = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
    return np.abs(residual) / np.sqrt(np.maximum(norm, 1e-300))


def two_view_pose(pair: PairMatches, threshold_px: float, seed: int = 0) -> tuple[np.ndarray, int] | None:
    """OpenCV's relative rotation R [3, 3] (cam2_from_cam1) and its inlier count, or None if too weak."""
    if len(pair.points1) < MIN_PAIR_INLIERS:
        return None
    cv2.setRNGSeed(seed)  # RANSAC draws from OpenCV's global generator; fix it so the check is repeatable
    # USAC_ACCURATE (graph-cut RANSAC with local optimisation): plain RANSAC returns the best minimal sample
    # unrefined, measured here 3x noisier (median 0.9 deg vs 0.2 deg on rendered views with exact poses).
    E, mask = cv2.findEssentialMat(pair.points1, pair.points2, np.eye(3), method=cv2.USAC_ACCURATE, prob=0.999,
                                   threshold=threshold_px / pair.pixel_scale)
    if E is None or E.shape != (3, 3) or int(mask.sum()) < MIN_PAIR_INLIERS:
        return None
    inliers = int(mask.sum())  # counted first: recoverPose prunes the mask in place (cheirality)
    _, R, _, _ = cv2.recoverPose(E, pair.points1, pair.points2, np.eye(3), mask=mask)
    return R, inliers


def _explained(pair: PairMatches, threshold_px: float) -> int:
    """How many of the pair's matches the reconstruction's relative pose explains (Sampson distance, pixels)."""
    t = pair.translation / max(float(np.linalg.norm(pair.translation)), 1e-300)
    dist = sampson_distance(skew(t) @ pair.rotation, pair.points1, pair.points2) * pair.pixel_scale
    return int((dist < threshold_px).sum())


def _verdict(pair: PairMatches, threshold_px: float) -> tuple[np.ndarray, int, bool] | None:
    """(two-view rotation [3, 3], its inlier count, whether the reconstruction contradicts the pair), or None when
    the pair is too weak to judge."""
    est = two_view_pose(pair, threshold_px)
    if est is None:
        return None
    R, inliers = est
    return R, inliers, _explained(pair, 2.0 * threshold_px) < EXPLAINED_FRACTION * inliers


def check_relative_poses(pairs: Sequence[PairMatches], limits: CheckLimits = CheckLimits()) -> PoseCheck:
    """Compare the reconstruction's relative pose of every pair with the pair's own two-view estimate."""
    counts = {True: [0, 0], False: [0, 0]}  # general? -> [compared, contradicted]
    weight_all, weight_bad, rot_err = 0, 0, []
    for pair in pairs:
        verdict = _verdict(pair, limits.threshold_px)
        if verdict is None:
            continue
        R, inliers, contradicted = verdict
        counts[pair.general][0] += 1
        counts[pair.general][1] += contradicted
        if pair.general:
            weight_all += inliers
            weight_bad += inliers * contradicted
            rot_err.append(rotation_angle_deg(R.T @ pair.rotation))
    median = float(np.median(rot_err)) if rot_err else float("nan")
    share = weight_bad / weight_all if weight_all else 0.0
    return PoseCheck(counts[True][0], counts[False][0], counts[True][1], counts[False][1], share, median, limits)


def torn_links(pairs: Sequence[PairMatches], limits: CheckLimits = CheckLimits()) -> list[tuple[str, str]]:
    """The names of the pairs the reconstruction contradicts, among ``pairs`` = a capture's images that follow each
    other in name order (video frames, a walk's photos).

    Such neighbours see nearly the same view, so their own matches fix their relative pose firmly; a model that
    contradicts one has torn the walk there. That is how a symmetric object folds a capture: an object with the
    same face on two sides (a can's label printed twice) on repeated texture (floor tiles) lets every pair of the
    far side match as the near side, and the mapper lays the two halves of the walk on one arc. The aggregate
    check above can miss it: the few torn links are a small share of all pairs (docs/commands/poses.md "Folded
    walks").
    """
    torn = []
    for pair in pairs:
        verdict = _verdict(pair, limits.threshold_px)
        if verdict is not None and verdict[2]:
            torn.append(pair.names)
    return torn
