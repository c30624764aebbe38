"""Ground-truth depth of training views (synth writes the exact z-depth of every pixel) at the training size.

Depth feeds the geometry loss (model/geometry_losses.py). The convention there: > 0 a surface at that camera z,
0 no surface (a sky, or the plain backdrop of an object scene), NaN unknown (a scene without depth files).
"""
from __future__ import annotations

import cv2
import numpy as np
import torch
from torch import Tensor

from ..errors import SceneError
from .data import TrainScene


def decode_depth(scene: TrainScene, index: int) -> Tensor:
    """Depth [H, W] float32 of view ``index`` at the training size, in the normalised scene's units.

    Nearest-pixel resizing: averaging depths across a silhouette would invent surfaces between object and
    backdrop. A scene without depth files gives all NaN.
    """
    height, width = scene.cameras.height, scene.cameras.width
    paths = scene.scene.depth_paths
    if paths is None or paths[index] is None:
        return torch.full((height, width), float("nan"))
    stored = cv2.imread(str(paths[index]), cv2.IMREAD_UNCHANGED)
    if stored is None or stored.ndim != 2:
        raise SceneError(f"{paths[index]}: not a single-channel depth image")
    depth = stored.astype(np.float32) * np.float32(scene.scene.depth_scale)
    if depth.shape != (height, width):
        depth = cv2.resize(depth, (width, height), interpolation=cv2.INTER_NEAREST_EXACT)
    return torch.from_numpy(depth)
