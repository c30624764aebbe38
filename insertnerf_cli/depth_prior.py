"""Fine samples guided by the scene's structure-from-motion points (render, eval and finetune).

The coarse pass finds surfaces by matching the references, which on real photos puts much of the weight off the
surface: the median depth error at SfM features is 7-13 % on the dev captures (docs/model-card.md, round 17),
and at references 10-30 degrees apart that fetches their colours many pixels away. A scene posed by COLMAP or
`insertnerf poses` knows where its textured surfaces are. Its points, projected into the target view and splatted
with a z-buffer (the nearest point wins), give a depth at most pixels; ``guide_weights`` then sends a share of the
fine samples to a narrow band around it and leaves the rest where the coarse pass put them, so the fine pass sees
both candidates and its densities decide (round 18, fast generator at 10 views: flower +2.9 dB, beer +1.2, room
+0.5, mold_gold_cape +0.4, each posed by COLMAP).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Sequence

import cv2
import numpy as np
import torch
from torch import Tensor

from .cameras import Cameras, check_shape
from .config import DEFAULT_VIEWS

if TYPE_CHECKING:
    from .scenes.points import ScenePoints

# The share of the fine samples' pdf put around the prior, and the band's width relative to its depth. A share
# of 1 loses room (-2.8 dB) where a wrong fill sends every sample off the surface; 0.75 keeps a quarter where the
# coarse pass has them (bench/sfm_prior_probe.py; docs/model-card.md round 18).
GUIDE_SHARE = 0.75
GUIDE_WIDTH = 0.05
# A frame whose SfM points lie past its far bound (more than 1 % of its prior's pixels: stray points hold fewer)
# gets that bound raised to two band widths past them, so the band fits inside [near, far] where the fine samples
# are drawn. A capture's own far bound can stop short of the background its references triangulate: 52 of
# mold_gold_cape's 60 eval frames at 3-16 views (round 26, at 10 views: fast +0.19 dB, full +0.42). Frames whose
# points lie inside it keep it: raising room's by the margin alone (3-5 %) moved single views by -0.40..+0.26 dB,
# the coarse grid's shift, not the scene; lowering the near bound alike lost room 0.18 dB; the farthest point
# instead of the 99th percentile, or a margin of 1.3, scored less on mold_gold_cape (bench/far_prior_probe.py).
PRIOR_FAR_QUANTILE = 0.99
PRIOR_FAR_MARGIN = 1.0 + 2.0 * GUIDE_WIDTH
# Splat radius and how far a splat's depth is carried into the empty pixels around it, as fractions of the
# frame's long side (2 and 12 px at eval's 256 px).
SPLAT_FRACTION = 2 / 256
REACH_FRACTION = 12 / 256
# A view's prior uses the points that one of its nearest references (at most this many; render's default count)
# observes: a point seen only from farther views is often hidden from it (round 19: at 16 views, capping at 10
# scored room 27.30 dB against 27.15 and mold_gold_cape 16.73 against 16.66; 6 scored within 0.07 dB of 10).
PRIOR_VIEWS = DEFAULT_VIEWS
# A point that this many of the views a frame may draw from observe is placed by as many rays; a two-view track
# by two, and its depth errs more. Room's COLMAP model holds a quarter of such tracks (the points we triangulate
# ourselves 1-2 %), and its frames score 0.2-0.3 dB more at 10-16 views when they splat only where the
# better-placed points leave the prior empty. Dropping them outright costs a capture of few photos, whose prior
# needs them (castle, 11 photos: -0.6 dB at 9 views); docs/model-card.md rounds 29-30.
WELL_TRACKED = 3


def view_prior(points: "ScenePoints", camera: Cameras, refs: Sequence[int],
               pool: Sequence[int] | None = None) -> Tensor | None:
    """[H, W] the prior of ``camera`` (1) from the points that two of its references ``refs`` (nearest first)
    observe and one of the PRIOR_VIEWS nearest does, or None when no point is left: points the frame's references
    would triangulate themselves, which they see, as the generator matching them does. Observations of any other
    view (eval's held-out photo, fine-tuning's target, a far photo that sees round an occluder) lend nothing; a
    sparse cloud would otherwise paint the far side of an object into the splats (rounds 19 and 25).
    With ``pool`` (every view the frame may draw its references from), the points fewer than WELL_TRACKED of those
    observe only fill the pixels the others leave without a prior."""
    found = view_prior_splats(points, camera, refs, pool)
    return None if found is None else found[0]


def view_prior_splats(points: "ScenePoints", camera: Cameras, refs: Sequence[int],
                      pool: Sequence[int] | None = None) -> tuple[Tensor, Tensor] | None:
    """(view_prior's [H, W] depth, [H, W] bool: the pixels a point's own splat covers, the rest of the prior being
    fill), or None as view_prior."""
    refs = list(refs)
    seen = points.seen_mask(refs, near=refs[:PRIOR_VIEWS])
    if not bool(seen.any()):
        return None
    if pool is None or points.observed is None:
        return prior_splats(points.xyz[seen], camera)
    placed = seen & well_tracked(points, pool)
    layers = [prior_splats(points.xyz[keep], camera) for keep in (placed, seen & ~placed) if bool(keep.any())]
    if len(layers) == 1:
        return layers[0]
    (first, first_splats), (second, second_splats) = layers
    return torch.where(torch.isnan(first), second, first), first_splats | second_splats


def well_tracked(points: "ScenePoints", pool: Sequence[int]) -> Tensor:
    """[P] bool: the points that WELL_TRACKED of the views in ``pool`` observe (observations known)."""
    return points.observers(list(pool)) >= WELL_TRACKED


def prior_depth(points: Tensor, camera: Cameras, reach_fraction: float | None = None) -> Tensor:
    """[H, W] camera-z depth of the nearest point splatted at each pixel of ``camera`` (1 camera), carried into
    empty pixels from the nearest splat within reach (``reach_fraction`` of the long side, default
    REACH_FRACTION; 0 carries none); NaN elsewhere. ``points`` [P, 3] are world positions."""
    return prior_splats(points, camera, reach_fraction)[0]


def prior_splats(points: Tensor, camera: Cameras, reach_fraction: float | None = None) -> tuple[Tensor, Tensor]:
    """(prior_depth [H, W], [H, W] bool: the pixels a point's own splat covers, before the fill)."""
    check_shape("points", points, (None, 3))
    if len(camera) != 1:
        raise ValueError(f"prior_depth projects into one camera, got {len(camera)}")
    height, width = camera.height, camera.width
    long_side = max(height, width)
    splat = max(1, round(SPLAT_FRACTION * long_side))
    reach = fill_reach(long_side) if reach_fraction is None else round(reach_fraction * long_side)
    uv, z = camera.to(device="cpu", dtype=torch.float64).project(points.to(device="cpu", dtype=torch.float64))
    front = z[0] > 1e-9  # uv is meaningless behind the camera
    depth = _splat(uv[0][front], z[0][front], height, width, splat)
    return _fill(depth, reach).to(camera.K.device), torch.isfinite(depth).to(camera.K.device)


def fill_reach(long_side: int) -> int:
    """How many px a splat's depth is carried into the empty pixels of a frame whose long side is ``long_side``
    (REACH_FRACTION, at least 1)."""
    return max(1, round(REACH_FRACTION * long_side))


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


def covering_far(far: float, prior: Tensor | None) -> float:
    """The far bound a frame with SfM depth ``prior`` [H, W] (NaN where none; None: no prior) is rendered with:
    ``far``, or where the prior's farthest depths (its PRIOR_FAR_QUANTILE) lie past it, a bound that holds the
    guide's band around them; never lowered."""
    if prior is None:
        return far
    depths = prior.detach().cpu().numpy()
    depths = depths[np.isfinite(depths)]  # numpy: torch.quantile refuses more than 2^24 values (a 20 MP frame)
    if depths.size == 0:
        return far
    reach = float(np.quantile(depths, PRIOR_FAR_QUANTILE))
    return far if reach <= far else PRIOR_FAR_MARGIN * reach


def guide_weights(weights: Tensor, t: Tensor, prior: Tensor, share: float = GUIDE_SHARE,
                  width: float = GUIDE_WIDTH) -> Tensor:
    """[R, S] coarse weights with ``share`` of each ray's total moved to a Gaussian of relative ``width`` around
    its ``prior`` depth [R] (on the sample depths t [R, S]); rays without a prior (NaN) or whose band holds no
    sample keep their weights. The total per ray is kept, so what reads the opacity is unchanged."""
    check_shape("t", t, weights.shape)
    check_shape("prior", prior, (weights.shape[0],))
    z = prior.to(weights)[:, None]  # [R, 1]
    band = torch.exp(-0.5 * ((t - z) / (width * z)) ** 2)
    mass = band.sum(dim=-1, keepdim=True)
    usable = torch.isfinite(z) & (mass > 1e-12)  # [R, 1]
    guided = (1.0 - share) * weights + share * band / mass.clamp(min=1e-12) * weights.sum(dim=-1, keepdim=True)
    return torch.where(usable, guided, weights)
