"""The SfM depth prior: the scene's structure-from-motion points as a depth per pixel of a frame.

A scene posed by COLMAP or `insertnerf poses` knows where its textured surfaces are. Its points, projected into a
frame and splatted with a z-buffer (the nearest point wins), less the splats a nearer surface encloses, then carried
a few pixels into the empty pixels around them, give a depth at most pixels. The renderer guides its fine samples
to it (model/guide.py), the blend at the prior tests the references there (rendering/prior_blend.py), and each
reference's own points make its occlusion map (sfm/occlusion_maps.py). Measured: docs/research-log.md, Sampling
and the SfM depth prior.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np
import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras, check_shape
from insertnerf_cli.config import DEFAULT_VIEWS
from insertnerf_cli.model.guide import GuideOptions
from insertnerf_cli.scenes.points import ScenePoints


# The 8 directions around a pixel, as (row, column) steps.
_DIRECTIONS = ((0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1))


@dataclass(frozen=True)
class PriorOptions:
    """Which points make a frame's prior and how they are drawn into it.

    Attributes:
        views: a point must be observed by one of the frame's this many nearest references (a point seen only
            from farther views is often hidden from it).
        well_tracked: points that at least this many of the frame's usable views observe are drawn first; the
            others (two-view tracks, placed less well) only fill the pixels those leave empty.
        splat_fraction: a point's disc radius, as a fraction of the frame's long side (2 px at 256).
        reach_fraction: how far a splat's depth is carried into empty pixels, as a fraction of the long side
            (12 px at 256).
        far_quantile: a frame whose points lie past its far bound (at this quantile of its prior's depths, so
            that stray points do not count) has the bound raised to hold the guide's band around them.
        enclosed_fraction, enclosed_directions, enclosed_margin: a splatted pixel is dropped (left to the fill)
            when in at least ``enclosed_directions`` of the 8 directions around it a splat within
            ``enclosed_fraction`` of the long side (16 px at 256) is nearer by more than ``enclosed_margin`` of its
            depth (drop_enclosed): mold_gold_cape +0.15 dB at 10 views and no flecks of the background on the
            cape, room -0.04, flower and procedural scenes level (docs/research-log.md). 9 directions: never.
    """

    views: int = DEFAULT_VIEWS
    well_tracked: int = 3
    splat_fraction: float = 2 / 256
    reach_fraction: float = 12 / 256
    far_quantile: float = 0.99
    enclosed_fraction: float = 16 / 256
    enclosed_directions: int = 6
    enclosed_margin: float = 0.15

    def __post_init__(self) -> None:
        if self.views < 1 or self.well_tracked < 1 or self.splat_fraction <= 0 or self.reach_fraction < 0 \
                or not 0.0 < self.far_quantile <= 1.0 or self.enclosed_fraction <= 0 \
                or not 1 <= self.enclosed_directions <= len(_DIRECTIONS) + 1 or self.enclosed_margin < 0:
            raise ValueError(f"invalid prior options {self}")

    def fill_reach(self, long_side: int) -> int:
        """How many px a splat's depth is carried into the empty pixels of a frame of ``long_side`` (at least 1)."""
        return max(1, round(self.reach_fraction * long_side))


def view_prior(points: ScenePoints, camera: Cameras, refs: Sequence[int], pool: Sequence[int] | None = None,
               options: PriorOptions = PriorOptions()) -> Tensor | None:
    """[H, W] the prior of ``camera`` (1) from the points that two of its references ``refs`` (nearest first)
    observe and one of the ``options.views`` nearest does, or None when no point is left: points the frame's
    references would triangulate themselves, which they see, as the generator matching them does. Observations of
    any other view (eval's held-out photo, fine-tuning's target, a far photo that sees round an occluder) lend
    nothing: a sparse cloud would otherwise paint the far side of an object into the splats.
    With ``pool`` (every view the frame may draw its references from), the points fewer than
    ``options.well_tracked`` of those observe only fill the pixels the others leave without a prior."""
    found = view_prior_splats(points, camera, refs, pool, options)
    return None if found is None else found[0]


def view_prior_splats(points: ScenePoints, camera: Cameras, refs: Sequence[int], pool: Sequence[int] | None = None,
                      options: PriorOptions = PriorOptions()) -> tuple[Tensor, Tensor] | None:
    """(view_prior's [H, W] depth, [H, W] bool: the pixels a point's own splat covers, the rest of the prior being
    fill), or None as view_prior."""
    refs = list(refs)
    seen = points.seen_mask(refs, near=refs[:options.views])
    if not bool(seen.any()):
        return None
    if pool is None or points.observed is None:
        return prior_splats(points.xyz[seen], camera, options)
    placed = seen & well_tracked(points, pool, options)
    layers = [prior_splats(points.xyz[keep], camera, options) for keep in (placed, seen & ~placed)
              if bool(keep.any())]
    if len(layers) == 1:
        return layers[0]
    (first, first_splats), (second, second_splats) = layers
    return torch.where(torch.isnan(first), second, first), first_splats | second_splats


def well_tracked(points: ScenePoints, pool: Sequence[int], options: PriorOptions = PriorOptions()) -> Tensor:
    """[P] bool: the points that ``options.well_tracked`` of the views in ``pool`` observe (observations known)."""
    return points.observers(list(pool)) >= options.well_tracked


def prior_depth(points: Tensor, camera: Cameras, options: PriorOptions = PriorOptions()) -> Tensor:
    """[H, W] camera-z depth of the nearest point splatted at each pixel of ``camera`` (1 camera), carried into
    empty pixels from the nearest splat within ``options.fill_reach``; NaN elsewhere. ``points`` [P, 3] are world
    positions."""
    return prior_splats(points, camera, options)[0]


def prior_splats(points: Tensor, camera: Cameras,
                 options: PriorOptions = PriorOptions()) -> tuple[Tensor, Tensor]:
    """(prior_depth [H, W], [H, W] bool: the pixels a point's own splat covers, before the fill)."""
    check_shape("points", points, (None, 3))
    if len(camera) != 1:
        raise ValueError(f"prior_depth projects into one camera, got {len(camera)}")
    height, width = camera.height, camera.width
    long_side = max(height, width)
    splat = max(1, round(options.splat_fraction * long_side))
    reach = options.fill_reach(long_side) if options.reach_fraction > 0 else 0
    uv, z = camera.to(device="cpu", dtype=torch.float64).project(points.to(device="cpu", dtype=torch.float64))
    front = z[0] > 1e-9  # uv is meaningless behind the camera
    depth = _splat(uv[0][front], z[0][front], height, width, splat)
    if options.enclosed_directions <= len(_DIRECTIONS):
        depth = drop_enclosed(depth, max(1, round(options.enclosed_fraction * long_side)),
                              options.enclosed_directions, options.enclosed_margin)
    return _fill(depth, reach).to(camera.K.device), torch.isfinite(depth).to(camera.K.device)


def _splat(uv: Tensor, z: Tensor, height: int, width: int, radius: int) -> Tensor:
    """[H, W] the smallest z of the discs of ``radius`` px around each point's pixel (inf where none)."""
    offsets = [(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)
               if dx * dx + dy * dy <= radius * radius]
    col, row = uv[:, 0].floor().long(), uv[:, 1].floor().long()
    out = torch.full((height * width,), math.inf, dtype=torch.float64)
    for dy, dx in offsets:
        r, c = row + dy, col + dx
        inside = (r >= 0) & (r < height) & (c >= 0) & (c < width)
        out.scatter_reduce_(0, (r * width + c)[inside], z[inside], reduce="amin")
    return out.reshape(height, width)


def drop_enclosed(depth: Tensor, reach: int, directions: int, margin: float) -> Tensor:
    """[H, W] splatted depth (inf where none) without the splats that nearer ones enclose: those that, in at least
    ``directions`` of the 8 directions around them, have a splat within ``reach`` px nearer by more than ``margin``
    times their depth.

    A glossy or plain surface carries few SfM points, and between their discs the points of what lies behind it
    show through: the prior there says "far", the fine samples and the blend at the prior follow it, and the
    frame shows flecks of the background on the subject (docs/research-log.md, Sampling and the SfM depth prior).
    Such a splat has the nearer surface all round it; one beside a silhouette has it on one side only and stays.
    """
    height, width = depth.shape
    # float32 is ample for a relative test of some percent and halves the time of the shifted minima.
    single = depth.float()
    padded = torch.nn.functional.pad(single[None, None], (reach, reach, reach, reach), value=math.inf)[0, 0]
    nearer = torch.zeros(depth.shape, dtype=torch.int64)
    for dy, dx in _DIRECTIONS:
        nearest = _min_along(padded, dy, dx, reach)[reach:reach + height, reach:reach + width]
        nearer += (nearest * (1.0 + margin) < single).long()
    return torch.where(torch.isfinite(depth) & (nearer >= directions), math.inf, depth)


def _min_along(padded: Tensor, dy: int, dx: int, reach: int) -> Tensor:
    """[H', W'] at each pixel the smallest value of ``padded`` at 1 .. ``reach`` steps of (dy, dx) from it (inf past
    the edge; the padding must be at least ``reach``), in log2(reach) shifted minima: windows of doubling length,
    then two overlapping ones of the largest power of two that fits."""
    def shifted(values: Tensor, steps: int) -> Tensor:
        return torch.roll(values, shifts=(-dy * steps, -dx * steps), dims=(0, 1))

    window = shifted(padded, 1)  # [1 .. 1]
    length = 1
    while 2 * length <= reach:
        window = torch.minimum(window, shifted(window, length))  # [1 .. 2 * length]
        length *= 2
    return torch.minimum(window, shifted(window, reach - length))  # [1 .. length] and [reach - length + 1 .. reach]


def _fill(depth: Tensor, reach: int) -> Tensor:
    """Empty (inf) pixels take the depth of the nearest splatted pixel within ``reach`` px, else NaN."""
    empty = ~torch.isfinite(depth)
    if bool(empty.all()):
        return torch.full_like(depth, math.nan)
    distance, labels = cv2.distanceTransformWithLabels(empty.numpy().astype(np.uint8), cv2.DIST_L2, 5,
                                                       labelType=cv2.DIST_LABEL_PIXEL)
    values = np.zeros(int(labels.max()) + 1)
    full = ~empty.numpy()
    values[labels[full]] = depth.numpy()[full]
    filled = values[labels]
    filled[distance > reach] = np.nan
    return torch.from_numpy(filled)


def covering_far(far: float, prior: Tensor | None, options: PriorOptions = PriorOptions(),
                 guide: GuideOptions = GuideOptions()) -> float:
    """The far bound a frame with SfM depth ``prior`` [H, W] (NaN where none; None: no prior) is rendered with:
    ``far``, or where the prior's farthest depths (its ``options.far_quantile``) lie past it, a bound that holds
    the guide's band around them; never lowered (a capture's own far bound can stop short of the background its
    references triangulate)."""
    if prior is None:
        return far
    depths = prior.detach().cpu().numpy()
    depths = depths[np.isfinite(depths)]  # numpy: torch.quantile refuses more than 2^24 values (a 20 MP frame)
    if depths.size == 0:
        return far
    reach = float(np.quantile(depths, options.far_quantile))
    return far if reach <= far else guide.band_reach * reach
