"""A training prior made the way render makes one from a scene's SfM points (train --guide-from features).

The simulated prior (training/guide.py) gives 70 % of the surface rays a depth wherever they are. Render's
prior is sparser and wrong in other places: COLMAP's points sit on texture (corners and blobs the references
match), each one is splatted into the target and carried up to 12 px into plain surfaces, and a point the
references see but the target does not (behind an occluder) paints the occluder's pixels with its farther depth.
Here every source view's corners (Shi-Tomasi, cv2.goodFeaturesToTrack) are lifted to world points with synth's
exact depth, the step's sources pool them, and depth_prior.prior_depth projects, splats and fills them into the
target: the same code render runs, on points that were found the way feature matching finds them.
"""
from __future__ import annotations

import cv2
import numpy as np
import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.sfm.depth_prior import prior_depth
from insertnerf_cli.training.data import decode_uint8
from insertnerf_cli.training.depth import decode_depth
from insertnerf_cli.training.device_data import SizeGroup, TrainingSet

# Corners per pixel of a source view (133 at 200 x 200), the weakest corner kept relative to the strongest, and
# their spacing; and each lifted point's relative depth error. Chosen so that the prior's cover and error match
# real triangulation on the same synth scenes: about half the pixels at a median error of a few percent
# (measured: docs/research-log.md, Sampling and the SfM depth prior).
CORNERS_PER_PIXEL = 1 / 300
CORNER_QUALITY = 0.01
CORNER_SPACING = 3
POINT_ERROR = 0.03


class FeaturePriors:
    """Per-view world points of the training set's corners (made once per view, then kept) and the step priors
    they give. A view's points are drawn with a generator seeded by its flat id, so --resume sees the same."""

    def __init__(self, data: TrainingSet) -> None:
        self.data = data
        self._points: dict[tuple[int, int], Tensor] = {}

    def step_prior(self, group: int, targets: Tensor, sources: Tensor, pixels: Tensor) -> Tensor:
        """[B * R / B] prior depths (NaN: none) at ``pixels`` [B, R / B] of the targets [B] of size group
        ``group``, from the corners of their sources [B, V] (flat view ids); the target's own are left out as
        eval leaves out the held-out photo's."""
        g = self.data.groups[group]
        out = []
        for target, row, where in zip(targets.tolist(), sources.tolist(), pixels.cpu()):
            pooled = [self.view_points(group, v) for v in dict.fromkeys(row) if v != target]
            points = torch.cat(pooled) if pooled else torch.zeros(0, 3)
            camera = Cameras(g.K[target:target + 1].cpu(), g.c2w[target:target + 1].cpu(), g.height, g.width)
            depth = prior_depth(points, camera) if len(points) else torch.full((g.height, g.width), float("nan"))
            out.append(depth.reshape(-1)[where].float())
        return torch.cat(out).to(self.data.device)

    def view_points(self, group: int, view: int) -> Tensor:
        """[P, 3] world points of the corners of flat view ``view`` that lie on a surface."""
        key = (group, view)
        if key not in self._points:
            self._points[key] = self._lift(self.data.groups[group], view)
        return self._points[key]

    def _lift(self, g: SizeGroup, view: int) -> Tensor:
        image, depth = self._image_and_depth(g, view)
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        most = max(1, round(CORNERS_PER_PIXEL * g.height * g.width))
        corners = cv2.goodFeaturesToTrack(gray, most, CORNER_QUALITY, CORNER_SPACING)
        if corners is None:
            return torch.zeros(0, 3)
        xy = corners.reshape(-1, 2)  # OpenCV's pixel centres are integers; ours sit at + 0.5
        z = depth[np.clip(np.rint(xy[:, 1]).astype(int), 0, g.height - 1),
                  np.clip(np.rint(xy[:, 0]).astype(int), 0, g.width - 1)]
        surface = np.isfinite(z) & (z > 0)
        if not surface.any():
            return torch.zeros(0, 3)
        rng = np.random.default_rng([view, 21])
        z = z[surface] * np.exp(POINT_ERROR * rng.standard_normal(int(surface.sum())))
        uv = torch.from_numpy(xy[surface] + 0.5).float()[None]  # [1, P, 2]
        camera = Cameras(g.K[view:view + 1].cpu(), g.c2w[view:view + 1].cpu(), g.height, g.width)
        return camera.unproject(uv, torch.from_numpy(z).float()[None])[0]

    def _image_and_depth(self, g: SizeGroup, view: int) -> tuple[np.ndarray, np.ndarray]:
        """uint8 [H, W, 3] and float32 [H, W] (0: no surface) of one flat view, on the host."""
        scene, index = g.views[view]
        stored = g.images[view] if g.images is not None else decode_uint8(self.data.scenes[scene], index)
        image = stored.cpu().numpy()
        if g.depths is not None:
            return image, g.depths[view].cpu().numpy()
        return image, decode_depth(self.data.scenes[scene], index).numpy()
