"""Ground-truth depth of training views (synth writes the exact z-depth of every pixel) at the training size.

Depth feeds the geometry loss (model/geometry_losses.py). The convention there: > 0 a surface at that camera z,
0 no surface (a sky, or the plain backdrop of an object scene), NaN unknown (a scene without depth files).
"""
from __future__ import annotations

import cv2
import numpy as np
import torch
from torch import Tensor

from insertnerf_cli.errors import SceneError
from insertnerf_cli.scenes import Scene
from insertnerf_cli.training.data import TrainScene


def read_scene_depth(scene: Scene, index: int, height: int, width: int) -> np.ndarray | None:
    """The depth file of view ``index`` as float32 [height, width] in the scene's units (0 = no surface), or None
    when the scene has no depth for it.

    Nearest-pixel resizing: averaging depths across a silhouette would invent surfaces between object and
    backdrop.
    """
    paths = scene.depth_paths
    if paths is None or paths[index] is None:
        return None
    stored = cv2.imread(str(paths[index]), cv2.IMREAD_UNCHANGED)
    if stored is None or stored.ndim != 2:
        raise SceneError(f"{paths[index]}: not a single-channel depth image")
    depth = stored.astype(np.float32) * np.float32(scene.depth_scale)
    if depth.shape != (height, width):
        depth = cv2.resize(depth, (width, height), interpolation=cv2.INTER_NEAREST_EXACT)
    return depth


def decode_depth(scene: TrainScene, index: int) -> Tensor:
    """Depth [H, W] float32 of view ``index`` at the training size, in the normalised scene's units; all NaN
    for a scene without depth files."""
    height, width = scene.cameras.height, scene.cameras.width
    depth = read_scene_depth(scene.scene, index, height, width)
    return torch.full((height, width), float("nan")) if depth is None else torch.from_numpy(depth)
