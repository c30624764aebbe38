"""Which reference views see a sample, and which see a nearer surface in front of it (render, eval, finetune).

On a capture walked round its object, a reference taken from another height or side often sees the object where
the target sees the support under it or the room behind it, and the generator, trained on synthetic scenes whose
views rarely disagree so, blends that colour in. Each reference's own SfM points say where its nearer surfaces are:
a depth map of the points it observes (sfm/occlusion_maps.py). A sample lying past that map by more than the
tolerance counts as unseen by that view, for the aggregators and the colour weights alike.

Two guards (measured: docs/research-log.md, Occlusion maps):
- a view nearly along the query ray sees what the target sees, and its map's errors (the fill carried across edges,
  a stray point) are all the test would add: views within ``near_angle`` of the ray are never masked;
- a sample that fewer than ``min_visible`` views pass keeps every view's say: the test picks among views, it never
  leaves a sample unseen (behind every map at once, as any sample behind a forward-facing scene's wall is).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from insertnerf_cli.cameras.camera import check_shape


@dataclass(frozen=True)
class Occlusion:
    """What the reference views' own SfM points say about their nearer surfaces.

    Attributes:
        depth: [V, 1, h, w] camera-z depth of the nearest surface each view sees (inf where its points say
            nothing), spanning the view's real image (no padding).
        near_angle: [V] radians: rays of a view closer than this to the query ray are never masked.
        tolerance: a sample farther from a view than its map's depth times 1 + tolerance is hidden from it.
        min_visible: where fewer views than this pass the test, every view that sees the sample keeps it.
    """

    depth: Tensor  # [V, 1, h, w]
    near_angle: Tensor  # [V]
    tolerance: float
    min_visible: int

    def __post_init__(self) -> None:
        check_shape("near_angle", self.near_angle, (self.depth.shape[0],))

    def select(self, rows: list[int]) -> "Occlusion":
        return Occlusion(self.depth[rows], self.near_angle[rows], self.tolerance, self.min_visible)

    def to(self, like: Tensor) -> "Occlusion":
        """On ``like``'s device and dtype."""
        return Occlusion(self.depth.to(like), self.near_angle.to(like), self.tolerance, self.min_visible)


def visible(occlusion: Occlusion, uv: Tensor, depth: Tensor, valid: Tensor, angle: Tensor, width: int,
            height: int) -> Tensor:
    """[V, 1, P] 1 where a view sees a sample: ``valid`` [V, 1, P] (in front and inside its image) and not past
    its map by more than ``occlusion.tolerance``, or nearer the query ray than its ``near_angle``. Pixel positions uv
    [V, 2, P] and camera depths [V, 1, P] as projection.pixel_coordinates gives them, ``angle`` [V, 1, P] as
    projection.ray_angle; where fewer than ``occlusion.min_visible`` views pass, ``valid``."""
    scale = torch.tensor([2.0 / width, 2.0 / height], dtype=uv.dtype, device=uv.device)[:, None]
    grid = (uv * scale - 1.0).transpose(1, 2)[:, None]  # [V, 1, P, 2]
    surface = F.grid_sample(occlusion.depth.to(uv), grid, mode="nearest", padding_mode="border",
                            align_corners=False)[:, :, 0]  # [V, 1, P]
    near = angle < occlusion.near_angle.to(angle)[:, None, None]
    seen = valid * ((depth <= surface * (1.0 + occlusion.tolerance)) | near).to(valid)
    return torch.where(seen.sum(dim=0, keepdim=True) >= occlusion.min_visible, seen, valid)
