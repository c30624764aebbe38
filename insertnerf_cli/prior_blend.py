"""Pixels whose references agree better at the SfM depth than at the rendered one take their blend there.

Issue 27, round 28 (docs/model-card.md): on mold_gold_cape the generator's depth sits a median 12 % off the depth of
the scene's SfM points on a third of the pixels, and sending its fine samples there does not move it (its density,
learned on synthetic scenes, prefers the gold's reflections). On those pixels a plain unstructured-lumigraph blend
of the references at the SfM depth scores 4 dB above the generator's colour. Where the SfM depth is the wrong
one (room's filled splats), the references disagree there and the generator's frame is kept. The test is the
references' colour variance over a small patch, as plane-sweep stereo matches: one pixel alone matches noise.

Round 34: where a point of the prior itself lands on the pixel (a splat, not a fill), its two candidates are mixed
rather than one taken, each weighted inversely to its patch variance squared. Neither test is sure on the gold's
glints or a shadow's edge, and the mean of two half-right colours errs less than either (eval, fast generator at 10
views: mold_gold_cape +0.14 dB, flower +0.44, room +0.11). A filled pixel still takes the blend only past MARGIN:
the fill carries a point's depth across edges it cannot see (mixed there too, room's 3 views gained 0.30 dB and its
10 views 0.12, so more views helped it less; docs/model-card.md round 34). Mixed 2 px past each splat as well:
mold_gold_cape +0.08 dB at 10 views, room +0.06 at 3 views and nothing at 10.

Round 35: the mix fades out over FEATHER_FRACTION instead of stopping at the disc's rim, which a 512-px render
showed as round spots; and a filled pixel is mixed too where every point the fill could carry lies on one smooth
surface (smooth_fill): the edges room's fills cross are where their points' depths jump.

Round 36: the rest of the fill is no longer all or nothing either: its share rises as (v_render / MARGIN v_prior)
cubed against 1, so a pixel near the margin, which neither test decides, takes part of each colour (fast
generator at 10 views: mold_gold_cape +0.04 dB, room +0.02, flower +0.08; docs/model-card.md round 36). And in an
object-centric capture the pixels no point lands on are tested at the frame's background plane the same way
(mold_gold_cape +0.10 dB at 10 views).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import Tensor

from .cameras import Cameras, check_shape
from .depth_prior import fill_reach
from .model.aggregate import angular_prior, weighted_moments
from .model.projection import Projected, project_samples
from .rays import Rays, rays_for_image

if TYPE_CHECKING:
    from .model import EncodedViews
    from .render import ImageOutput

# The blend: the lumigraph weights of the 8 views nearest in angle (K = 6 and 11 scored 0.1-0.2 dB less on
# mold_gold_cape's covered pixels: bench/ibr_baseline.py --k). The agreement: the variance of the views the blend
# weighs, under its weights. Until round 35 it took the 4 nearest, as the generator's photo-consistency cue does
# (ModelConfig.consistency_views); 6 / 8 scored mold_gold_cape 18.47 / 18.48 dB at 10 views against 18.44 (full
# generator 18.43 against 18.36), room 28.38 / 28.39 against 28.35, flower 27.87 / 27.86 against 27.87.
BLEND_VIEWS = 8
AGREE_VIEWS = BLEND_VIEWS
# The patch the variance is averaged over, as a fraction of the frame's long side (7 px at eval's 256 px).
WINDOW_FRACTION = 7 / 256
# A filled pixel's blend weighs (v_render / (MARGIN v_prior)) ** FILL_POWER against the frame's colour (v: patch
# variance): half where the references agree MARGIN times better at the prior than at the rendered depth, nearly
# all or nothing a factor 2 either side. Until round 36 it was all or nothing at MARGIN (power infinite); power 3
# scored (fast generator) mold_gold_cape 18.59 dB at 10 views against 18.55, room 27.36 / 28.41 at 3 / 10 views
# against 27.27 / 28.39, flower 26.85 / 27.94 against 26.77 / 27.86. In round 34 a splat's power 2 with margin 1.5
# cut room's 3-to-10 gain to +0.95.
MARGIN = 1.5
FILL_POWER = 3.0
# A splatted pixel's blend weighs (v_render / v_prior) ** MIX_POWER against the frame's colour.
# Power 1 scored as 2 on mold_gold_cape (18.49 against 18.48 dB, mixed on every pixel) and room 0.08 dB less at 10.
MIX_POWER = 2.0
# The variance of a point fewer than two references see: above any of colours in [0, 1] (3 channels x 1/4), so
# such a point never wins, and a patch holding a few still can.
UNSEEN_COST = 1.0
# A filled pixel whose fill could come from splats (those within the fill's reach) that lie this close in depth, as
# a fraction of the nearest, sits on one smooth surface and is mixed like a splat; elsewhere the fill may carry a
# point's depth across an edge, and the all-or-nothing rule stays (round 35, fast generator at 10 views: 0.05 /
# 0.15 / 0.25 / 0.4 gave mold_gold_cape 18.41 / 18.44 / 18.45 / 18.46 dB, room's 3-to-10 gain +1.07 / +1.08 / - /
# +1.04; round 34's probe with every fill mixed: +0.87).
SMOOTH_SPAN = 0.15
# The window over which a splatted pixel's mix fades into the rule around it, as a fraction of the long side (5 px
# at 256: 2 px past a 2-px disc). Inside it the mix's part is the window's share covered by mixed pixels, so an
# isolated disc has no rim: a hard edge at the disc drew round gold spots into mold_gold_cape's opening at 512 px
# (round 35).
FEATHER_FRACTION = 5 / 256
# In an object-centric capture a pixel no SfM point lands on (mold_gold_cape's lab, 22 % of its pixels and a third
# of its error) mixes in the references' blend at the frame's background plane, the BACKGROUND_QUANTILE of its
# prior's depths, with a share (v_render / (BACKGROUND_MARGIN v_plane)) ** BACKGROUND_POWER against 1. The
# generator, trained on scenes whose backgrounds are plain or near, sets such pixels at the object's depth, where
# the references disagree; far surfaces move little between nearby views, so a plane near their depth lines them up
# (round 36). Power 3 at margin 3 takes the plane only where its references agree clearly better: fast generator,
# mold_gold_cape 17.23 / 18.59 -> 17.29 / 18.69 dB at 3 / 10 views, beer 23.84 / 24.35 -> 23.83 / 24.41. Power 1
# at margin 1.5 scored mold_gold_cape 18.76 at 10 but cost beer's 3 views 1.4 dB (scored offline), whose folded
# poses give its few references backgrounds from two sides of the room. Forward-facing captures are left out:
# their bare pixels are walls at the points' own depths; there the plane lifted 3 views (room +0.05 to +0.18 dB,
# flower +0.02 to +0.23) and left 10 views at best unchanged (room -0.09 to +0.01).
BACKGROUND_QUANTILE = 0.9
BACKGROUND_MARGIN = 3.0
BACKGROUND_POWER = 3.0
# Pixels reprojected per pass: [V, 3 + 3 + 4 + 1, P] floats (colours, finer colours, ray_diff, mask) for 10 views
# stay near 30 MB.
PIXELS_PER_PASS = 65536


def reference_colours(encoded: "EncodedViews", rays: Rays, depth: Tensor, finer: bool = True) -> Projected:
    """What each reference sees of R rays' points at camera-z ``depth`` [R] (the rays' directions have z = 1;
    NaN: nothing there, masked out): colours [V, 3, R] at the frame's size, finer ones where encoded holds them
    and ``finer`` asks (only a blend reads them), mask [V, 1, R] (0 also where a reference's occlusion map, when
    encoded holds them, hides the point), ray_diff [V, 4, R]."""
    known = torch.isfinite(depth)
    points = rays.origins + rays.directions * torch.where(known, depth, torch.ones_like(depth))[:, None]  # [R, 3]
    # A reference whose own points show a nearer surface in front of the point does not see it (occlusion_maps;
    # round 32 measured nothing from this, before the fill was mixed; round 35: mold_gold_cape +0.07 dB at 10 views,
    # room and flower unchanged).
    seen = project_samples(encoded, points[:, None], rays.directions, finer=finer, features=False).unoccluded()
    return Projected((), seen.colours, seen.mask * known.to(seen.mask)[None, None], seen.ray_diff, seen.finer)


def variance(seen: Projected, weights: Tensor | None = None) -> Tensor:
    """[R] the references' summed RGB variance at each point under the lumigraph weights [V, 1, R] of the
    AGREE_VIEWS views nearest in angle (``weights``: those, computed already); UNSEEN_COST where fewer than two
    views see it."""
    if weights is None:
        weights = angular_prior(seen.ray_diff, seen.mask, AGREE_VIEWS)
    _, var = weighted_moments(seen.colours, weights)  # [1, 3, R]
    lonely = seen.mask.sum(dim=(0, 1)) < 2
    return torch.where(lonely, torch.full_like(var[0, 0], UNSEEN_COST), var.sum(dim=1)[0])


def blend(seen: Projected, weights: Tensor | None = None) -> Tensor:
    """[R, 3] the lumigraph blend of the BLEND_VIEWS references nearest in angle (finer colours where held) under
    their weights [V, 1, R] (``weights``: those, computed already)."""
    if weights is None:
        weights = angular_prior(seen.ray_diff, seen.mask, BLEND_VIEWS)
    return (seen.blend_colours * weights).sum(dim=0).T


def patch_mean(cost: Tensor, size: tuple[int, int], fraction: float = WINDOW_FRACTION) -> Tensor:
    """[R] per-pixel ``cost`` [R] averaged over a square patch of ``fraction`` of the long side (odd, centred;
    the pixels inside the frame only)."""
    window = max(1, round(fraction * max(size))) | 1
    return F.avg_pool2d(cost.reshape(1, 1, *size), window, stride=1, padding=window // 2,
                        count_include_pad=False).reshape(-1)


def blend_at_prior(frame: "ImageOutput", encoded: "EncodedViews", camera: Cameras, prior: Tensor,
                   far: float, splatted: Tensor | None = None, background: bool = False) -> "ImageOutput":
    """``frame`` with its references' blend at the ``prior`` depth [H, W] (NaN: none) given where they agree there:
    each pixel's share of the blend rises steeply (FILL_POWER) through one half where its references agree MARGIN
    times better at the prior than at the frame's own depth; near the pixels ``splatted`` [H, W] (bool: a prior
    point's own disc; None: none) and the fill between splats on one smooth surface (smooth_fill), that share
    moves to a splat's gentler mix_share by the part of a FEATHER_FRACTION window they cover. Depth: the prior where
    the blend's share passes one half; opacity kept. A prior past ``far``, the bound the frame was rendered within,
    is left out: depth files sized for it hold every pixel. ``background`` (object-centric captures): the pixels
    without a prior mix in the blend at the frame's background plane (background_plane) the same way."""
    from .render import ImageOutput

    height, width = camera.height, camera.width
    check_shape("prior", prior, (height, width))
    param = encoded.images
    camera = camera.to(device=param.device, dtype=param.dtype)
    prior_flat, rendered = prior.to(param).reshape(-1), frame.depth.to(param).reshape(-1)  # [R] each
    ones = param.new_ones(1)
    rays = rays_for_image(camera, ones, ones)
    size = (height, width)
    at_prior = looked_up(encoded, rays, prior_flat)
    # The rendered depth is only tested, never blended at: no finer colours.
    agree_render = patch_mean(looked_up(encoded, rays, rendered, colours=False).variance, size)
    agree_prior, colours, target = patch_mean(at_prior.variance, size), at_prior.colours, prior_flat
    # A pixel whose own prior point fewer than two references see has no blend to speak of (none: black), however
    # well its patch agrees.
    usable = (prior_flat <= far) & at_prior.seen_twice  # [R]; NaN: False
    share = torch.where(usable, mix_share(agree_prior, agree_render, FILL_POWER, MARGIN), 0.0)  # [R] the blend's share
    if splatted is not None:
        check_shape("splatted", splatted, (height, width))
        mixed = splatted.to(prior.device) | smooth_fill(prior, splatted)  # [H, W]
        share = torch.where(usable, feathered(share, mix_share(agree_prior, agree_render), mixed), share)
    bare, plane = ~torch.isfinite(prior_flat), background_plane(prior, far) if background else None
    if plane is not None and bool(bare.any()):
        at_plane = looked_up(encoded, rays, torch.full_like(prior_flat, plane))
        agree_plane = patch_mean(at_plane.variance, size)
        plane_share = mix_share(agree_plane, agree_render, BACKGROUND_POWER, BACKGROUND_MARGIN)
        share = torch.where(bare & at_plane.seen_twice, plane_share, share)
        colours = torch.where(bare[:, None], at_plane.colours, colours)
        target = torch.where(bare, torch.full_like(prior_flat, plane), prior_flat)
    own, blended, weight = frame.rgb.reshape(-1, 3), colours.to(frame.rgb), share.to(frame.rgb)[:, None]
    # where(), not lerp() alone: a pixel the blend does not enter keeps its colour exactly, whatever the blend holds.
    rgb = torch.where(weight > 0, torch.lerp(own, blended, weight), own).clamp(0.0, 1.0)
    depth = torch.where(share > 0.5, target.to(frame.depth), frame.depth.reshape(-1))
    return ImageOutput(rgb=rgb.reshape(height, width, 3), depth=depth.reshape(height, width), opacity=frame.opacity)


@dataclass(frozen=True)
class LookedUp:
    """The references at one depth per pixel: their patch-free variance [R] (variance()), blend [R, 3] (blend())
    and whether at least two of them see the point [R] (bool)."""

    variance: Tensor
    colours: Tensor
    seen_twice: Tensor


def looked_up(encoded: "EncodedViews", rays: Rays, depth: Tensor, colours: bool = True) -> LookedUp:
    """The references at camera-z ``depth`` [R] along R ``rays`` (NaN: nothing there), PIXELS_PER_PASS at a time;
    ``colours`` False: the variance alone (LookedUp.colours empty, [R, 0])."""
    parts = []
    for start in range(0, len(rays), PIXELS_PER_PASS):
        seen = reference_colours(encoded, rays[start:start + PIXELS_PER_PASS], depth[start:start + PIXELS_PER_PASS],
                                 finer=colours)
        # One set of lumigraph weights serves the variance and the blend where their view counts agree.
        weights = angular_prior(seen.ray_diff, seen.mask, BLEND_VIEWS)  # [V, 1, R]
        agree = weights if AGREE_VIEWS == BLEND_VIEWS else None
        blended = blend(seen, weights) if colours else seen.colours.new_zeros(seen.colours.shape[-1], 0)
        parts.append((variance(seen, agree), blended, seen.mask.sum(dim=(0, 1)) >= 2))
    return LookedUp(*(torch.cat(p) for p in zip(*parts)))


def background_plane(prior: Tensor, far: float) -> float | None:
    """The camera-z depth [scalar] of a frame's background: the BACKGROUND_QUANTILE of its ``prior`` [H, W] depths
    within ``far``; None where it has none."""
    depths = prior[torch.isfinite(prior) & (prior <= far)].double()
    if depths.numel() == 0:
        return None
    rank = min(depths.numel(), max(1, round(BACKGROUND_QUANTILE * depths.numel())))
    return float(depths.kthvalue(rank).values)


def feathered(hard: Tensor, mix: Tensor, mixed: Tensor) -> Tensor:
    """[R] the blend's share: ``hard`` [R] (the all-or-nothing rule's) moved toward ``mix`` [R] by the part of each
    pixel's FEATHER_FRACTION window that the pixels ``mixed`` [H, W] (bool) cover."""
    cover = patch_mean(mixed.to(hard).reshape(-1), (mixed.shape[0], mixed.shape[1]), FEATHER_FRACTION)  # [R]
    return torch.lerp(hard, mix, cover)


def smooth_fill(prior: Tensor, splatted: Tensor) -> Tensor:
    """[H, W] bool: the filled pixels of ``prior`` [H, W] (NaN: none) whose splats within the fill's reach (a square
    of 2 reach + 1 px, depth_prior.fill_reach; ``splatted`` [H, W]: a point's own disc) lie no more than
    SMOOTH_SPAN of the nearest one's depth behind it: every point the fill could have taken lies on one surface."""
    check_shape("splatted", splatted, tuple(prior.shape))
    window = 2 * fill_reach(max(prior.shape)) + 1
    depth, splats = prior.double(), splatted.to(prior.device)  # [H, W] each

    def largest(values: Tensor) -> Tensor:  # [H, W] the largest of ``values`` on the splats in each window
        on_splats = torch.where(splats, values, -torch.inf)[None, None]  # [1, 1, H, W]
        return F.max_pool2d(on_splats, window, stride=1, padding=window // 2)[0, 0]

    nearest, farthest = -largest(-depth), largest(depth)
    filled = torch.isfinite(prior) & ~splats
    return filled & torch.isfinite(nearest) & (farthest <= nearest * (1.0 + SMOOTH_SPAN))


def mix_share(at_prior: Tensor, at_render: Tensor, power: float = MIX_POWER, margin: float = 1.0) -> Tensor:
    """[R] the blend's share of a pixel's colour from the references' patch variances [R] at the prior and at the
    rendered depth: at_render ** p / (at_render ** p + (margin at_prior) ** p), p = ``power`` (a splat's MIX_POWER
    by default); 0 (the frame's colour) where both are 0."""
    render_term, prior_term = at_render ** power, (margin * at_prior) ** power
    total = render_term + prior_term
    share = render_term / total.clamp(min=torch.finfo(total.dtype).tiny)
    return torch.where(total > 0, share, torch.zeros_like(total))
