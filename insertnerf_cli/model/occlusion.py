"""Which reference views see a sample, and which see a nearer surface in front of it (render, eval, finetune).

Issue 27, round 32 (docs/model-card.md): on a capture walked round its object, a reference taken from another
height or side often sees the object where the target sees the tissue under it or the lab behind it, and the
generator, trained on synthetic scenes whose views rarely disagree so, blends that colour in (mold_gold_cape's gold
smears). Each reference's own SfM points say where its nearer surfaces are: a depth map of the points it observes
(the library's splat and fill, ``occlusion_maps``). A sample lying past that map by more than OCCLUSION_TOLERANCE
counts as unseen by that view, for the aggregators and the colour weights alike.

Two guards, from the probes (bench/sfm_visibility_probe.py):
- a view nearly along the query ray sees what the target sees, and its map's errors (the fill carried across edges,
  a stray point) are all the test would add: views within NEAR_PARALLAX of the ray, in parallax per unit of
  relative depth as a fraction of the view's long side, are never masked. Room's 41 forward-facing photos lost
  0.8 dB at 10 views without it; with it they are untouched, while mold_gold_cape's long lens (2.7 times room's
  focal length over the long side) still tests all but its views within about 3 degrees.
- a sample that fewer than MIN_VISIBLE views pass keeps every view's say: the test picks among views, it never
  leaves a sample unseen (behind every map at once, as any sample behind a forward-facing scene's wall is).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from ..cameras import check_shape

# A sample farther from a view than its map's depth times 1 + this is hidden from it (0.15: mold_gold_cape
# 0.2 dB lower at 10 views; round 21's probe).
OCCLUSION_TOLERANCE = 0.3
# Views whose ray through a sample lies within this parallax of the query ray are never masked: the angle times
# the view's focal length over its long side. 0.12 is 3.3 degrees through mold_gold_cape's 27-degree lens, 6.8
# through the castle's 53 and 7.9-8.9 through room's, flower's and beer's 60-66. Round 32: 0.08 scored
# mold_gold_cape the same (18.10 dB at 10 views against 18.11) and cost the castle's 11 photos 0.14 dB at 6-9
# views (0.12: 0.05); 0.16 lost mold_gold_cape 0.06; room needs at least 5 degrees.
NEAR_PARALLAX = 0.12
MIN_VISIBLE = 2


@dataclass(frozen=True)
class Occlusion:
    """What the reference views' own SfM points say about their nearer surfaces.

    Attributes:
        depth: [V, 1, h, w] camera-z depth of the nearest surface each view sees (inf where its points say
            nothing), spanning the view's real image (no padding).
        near_angle: [V] radians: rays of a view closer than this to the query ray are never masked
            (NEAR_PARALLAX over the view's focal length per long side).
    """

    depth: Tensor  # [V, 1, h, w]
    near_angle: Tensor  # [V]

    def __post_init__(self) -> None:
        check_shape("near_angle", self.near_angle, (self.depth.shape[0],))

    def select(self, rows: list[int]) -> "Occlusion":
        return Occlusion(self.depth[rows], self.near_angle[rows])

    def to(self, like: Tensor) -> "Occlusion":
        """On ``like``'s device and dtype."""
        return Occlusion(self.depth.to(like), self.near_angle.to(like))


def visible(occlusion: Occlusion, uv: Tensor, depth: Tensor, valid: Tensor, angle: Tensor, width: int,
            height: int) -> Tensor:
    """[V, 1, P] 1 where a view sees a sample: ``valid`` [V, 1, P] (in front and inside its image) and not past
    its map by more than OCCLUSION_TOLERANCE, or nearer the query ray than its ``near_angle``. Pixel positions uv
    [V, 2, P] and camera depths [V, 1, P] as projection.pixel_coordinates gives them, ``angle`` [V, 1, P] as
    projection.ray_angle; where fewer than MIN_VISIBLE views pass, ``valid``."""
    scale = torch.tensor([2.0 / width, 2.0 / height], dtype=uv.dtype, device=uv.device)[:, None]
    grid = (uv * scale - 1.0).transpose(1, 2)[:, None]  # [V, 1, P, 2]
    surface = F.grid_sample(occlusion.depth.to(uv), grid, mode="nearest", padding_mode="border",
                            align_corners=False)[:, :, 0]  # [V, 1, P]
    near = angle < occlusion.near_angle.to(angle)[:, None, None]
    seen = valid * ((depth <= surface * (1.0 + OCCLUSION_TOLERANCE)) | near).to(valid)
    return torch.where(seen.sum(dim=0, keepdim=True) >= MIN_VISIBLE, seen, valid)
