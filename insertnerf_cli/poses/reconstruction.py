"""Reading what COLMAP built: a model's relative poses beside the database's own matches (for the pose check and
the torn-walk test), a database with its matches cleared, undistortion, and the model as plain arrays. The pycolmap
calls of `insertnerf poses` that read rather than build live here; estimate.py runs the pipeline.
"""
from __future__ import annotations

import os
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import pycolmap

from insertnerf_cli.errors import UserError
from insertnerf_cli.poses.check import MIN_PAIR_INLIERS, CheckLimits, PairMatches, torn_links
from insertnerf_cli.poses.folder import ModelArrays

GENERAL_CONFIGS = (pycolmap.TwoViewGeometryConfiguration.CALIBRATED,
                   pycolmap.TwoViewGeometryConfiguration.UNCALIBRATED)
PLANAR_CONFIGS = (pycolmap.TwoViewGeometryConfiguration.PLANAR,
                  pycolmap.TwoViewGeometryConfiguration.PANORAMIC,
                  pycolmap.TwoViewGeometryConfiguration.PLANAR_OR_PANORAMIC)


def cam_from_world(image: "pycolmap.Image") -> np.ndarray:
    """World-to-camera [3, 4] of a registered image. pycolmap >= 3.12 made ``cam_from_world`` a method."""
    pose = image.cam_from_world
    pose = pose() if callable(pose) else pose
    return np.asarray(pose.matrix(), dtype=np.float64)


def scaled_limits(check: CheckLimits, longest_side: int, max_image_size: int) -> CheckLimits:
    """The check's limits in the keypoints' pixels: full resolution, where SIFT saw the image shrunk to
    max_image_size."""
    shrink = max(1.0, longest_side / max_image_size)
    return replace(check, threshold_px=check.threshold_px * shrink)


def pair_matches(db_path: Path, rec: "pycolmap.Reconstruction", max_pairs: int,
                 keep: Callable[[str, str], bool] = lambda a, b: True) -> list[PairMatches]:
    """Raw matches (normalised coordinates) and model relative poses of up to ``max_pairs`` registered pairs
    whose image names ``keep`` accepts.

    General (non-planar) pairs come first, most matches first: a torn trajectory shows in its strongest links.
    """
    poses = {i: cam_from_world(img) for i, img in rec.images.items() if img.has_pose}
    with pycolmap.Database.open(db_path) as db:
        pair_ids, geometries = db.read_two_view_geometries()
        pairs = [(*pycolmap.pair_id_to_image_pair(p), g.config in GENERAL_CONFIGS, len(g.inlier_matches))
                 for p, g in zip(pair_ids, geometries)
                 if len(g.inlier_matches) >= MIN_PAIR_INLIERS and g.config in GENERAL_CONFIGS + PLANAR_CONFIGS]
        pairs = sorted((p for p in pairs if p[0] in poses and p[1] in poses
                        and keep(rec.images[p[0]].name, rec.images[p[1]].name)), key=lambda p: (not p[2], -p[3]))
        keypoints: dict[int, np.ndarray] = {}
        out = []
        for a, b, general, _ in pairs[:max_pairs]:
            for i in (a, b):
                if i not in keypoints:  # normalised camera coordinates [K, 2], distortion removed
                    keypoints[i] = rec.images[i].camera.cam_from_img(db.read_keypoints(i)[:, :2].astype(np.float64))
            matches = db.read_matches(a, b).astype(np.int64)  # [M, 2]
            r1, t1, r2, t2 = poses[a][:, :3], poses[a][:, 3], poses[b][:, :3], poses[b][:, 3]
            rot = r2 @ r1.T
            out.append(PairMatches((rec.images[a].name, rec.images[b].name), keypoints[a][matches[:, 0]],
                                   keypoints[b][matches[:, 1]], rot, t2 - rot @ t1,
                                   float(rec.images[a].camera.mean_focal_length()), general))
    return out


def torn_neighbours(rec: "pycolmap.Reconstruction", db_path: Path, names: Sequence[str],
                    limits: CheckLimits) -> list[tuple[str, str]]:
    """Pairs of images next to each other in ``names`` (the capture's name order) that the model contradicts
    (check.torn_links)."""
    place = {name: k for k, name in enumerate(names)}
    return torn_links(pair_matches(db_path, rec, len(names), lambda a, b: abs(place[a] - place[b]) == 1), limits)


def features_only(db_path: Path, copy: Path) -> None:
    """A copy of the database with its images and features but no matches (no COLMAP process has it open now)."""
    for suffix in ("", "-wal", "-shm"):  # SQLite's journal files, when they outlived the last connection
        if Path(f"{db_path}{suffix}").exists():
            shutil.copyfile(f"{db_path}{suffix}", f"{copy}{suffix}")
    with pycolmap.Database.open(copy) as db:
        db.clear_matches()
        db.clear_two_view_geometries()


def undistort(model_dir: Path, image_dir: Path, tmp: Path) -> "pycolmap.Reconstruction":
    """Undistort images and model to PINHOLE; move them to ``tmp/images`` and ``tmp/colmap/sparse/0``."""
    staging = tmp / "colmap" / "undistorted"
    pycolmap.undistort_images(staging, model_dir, image_dir)
    os.replace(staging / "images", tmp / "images")
    (tmp / "colmap" / "sparse").mkdir(parents=True, exist_ok=True)
    os.replace(staging / "sparse", tmp / "colmap" / "sparse" / "0")
    shutil.rmtree(staging)
    return pycolmap.Reconstruction(tmp / "colmap" / "sparse" / "0")


def model_arrays(rec: "pycolmap.Reconstruction") -> ModelArrays:
    """Registered images (sorted by name), their cameras and the points each sees, as plain arrays."""
    images = sorted((img for img in rec.images.values() if img.has_pose), key=lambda img: img.name)
    sizes = {(img.camera.height, img.camera.width) for img in images}
    if len(sizes) != 1:
        raise UserError(f"the undistorted cameras have {len(sizes)} different image sizes {sorted(sizes)}; "
                        "resize the input images to one size and run again.")
    point_ids = np.array(sorted(rec.points3D), dtype=np.int64)
    index = {int(pid): i for i, pid in enumerate(point_ids)}
    xyz = np.array([rec.points3D[int(p)].xyz for p in point_ids], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([rec.points3D[int(p)].color for p in point_ids], dtype=np.uint8).reshape(-1, 3)
    seen = [np.array([index[p.point3D_id] for p in img.get_observation_points2D()], dtype=np.int64)
            for img in images]
    (height, width), = sizes
    return ModelArrays(names=tuple(img.name for img in images),
                       K=np.stack([img.camera.calibration_matrix() for img in images]),
                       w2c=np.stack([cam_from_world(img) for img in images]), height=height, width=width,
                       image_ids=tuple(int(img.image_id) for img in images), xyz=xyz, rgb=rgb, seen=seen)
