"""LLFF scenes: ``poses_bounds.npy`` [N, 17] with ``images/`` (or a chosen ``images_N/``).

Row i belongs to the i-th image in name order. Its first 15 values are a 3x5 matrix: [down, right, back]
rotation columns, the centre, and [H, W, f] at full resolution; the last two are near/far. The principal
point is the image centre and fx = fy = f; K is scaled to the images actually read.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from insertnerf_cli.cameras.camera import intrinsics, llff_to_opencv
from insertnerf_cli.errors import SceneError
from insertnerf_cli.scenes.base import Scene
from insertnerf_cli.scenes.binfiles import load_npy
from insertnerf_cli.scenes.colmap_model import aligned_model_points
from insertnerf_cli.scenes.common import ReadViews, assemble, safe_path
from insertnerf_cli.scenes.images import find_images

FILENAME = "poses_bounds.npy"
_ROW = 17  # 3x5 pose-and-hwf matrix + near + far


def load_poses_bounds(path: Path) -> np.ndarray:
    """The [N, 17] array, checked (no pickles: the file is data, not code)."""
    data = load_npy(path)  # checks the header's shape against the bytes held before allocating
    if data.ndim != 2 or data.shape[1] != _ROW or data.shape[0] == 0 or not np.issubdtype(data.dtype, np.number):
        raise SceneError(f"{path}: expected an [N, {_ROW}] array of numbers, got shape {list(data.shape)} "
                         f"of {data.dtype}")
    bad = np.flatnonzero(~np.isfinite(data.astype(np.float64)).all(axis=1))
    if len(bad):
        raise SceneError(f"{path}: {len(bad)} of {len(data)} rows hold NaN or infinity (row {bad[0]} first); every "
                         f"row needs {_ROW} finite numbers; re-create the file (e.g. with `insertnerf poses`)")
    return data.astype(np.float64)


def read_llff(root: Path, images: str, background: tuple[float, float, float]) -> Scene:
    data = load_poses_bounds(root / FILENAME)
    folder = safe_path(root, images, "images folder")
    if not folder.is_dir():
        raise SceneError(f"{root}: no {images}/ folder beside {FILENAME}")
    paths = find_images(folder)
    if len(paths) != len(data):
        raise SceneError(f"{root}: {FILENAME} has {len(data)} poses but {images}/ holds {len(paths)} images; "
                         "LLFF needs exactly one image per pose (remove unregistered images)")
    mats = torch.from_numpy(data[:, :15].reshape(-1, 3, 5))  # [N, 3, 5]
    hwf = mats[:, :, 4]
    K = torch.stack([intrinsics(float(f), float(f), 0.5 * float(w), 0.5 * float(h)) for h, w, f in hwf])
    sizes = [(int(round(float(h))), int(round(float(w)))) for h, w, _ in hwf]
    bounds = torch.from_numpy(data[:, 15:])
    c2w = llff_to_opencv(mats[:, :, :4])
    views = ReadViews(root=root, paths=paths, K=K, c2w=c2w, format="llff", sizes=sizes, near=bounds[:, 0],
                      far=bounds[:, 1], points=aligned_model_points(root, c2w, paths), source=root / FILENAME)
    return assemble(views, background)
