"""Pixels whose references agree better at the SfM depth than at the rendered one take their blend there.

Where the generator's depth sits off the depth of the scene's SfM points and its fine samples sent there do not move
it (its density, learned on synthetic scenes, can prefer reflections), a plain unstructured-lumigraph blend of the
references at the SfM depth is often the better colour. Where the SfM depth is the wrong one (a fill carried
across an edge), the references disagree there and the generator's frame is kept. The test is the references'
colour variance over a small patch, as plane-sweep stereo matches: one pixel alone matches noise.

- A pixel a prior point itself lands on (a splat) mixes its two candidates, each weighted inversely to its patch
  variance squared: neither test is sure on glints or a shadow's edge, and the mean of two half-right colours errs
  less than either. The mix fades out over a window around the splats instead of stopping at their rims.
- A filled pixel takes the blend with a share that rises steeply through one half where its references agree
  ``margin`` times better at the prior: the fill carries a point's depth across edges it cannot see. Where every
  point the fill could carry lies on one smooth surface (smooth_fill), it is mixed like a splat.
- In an object-centric capture, the pixels no point lands on are tested the same way at the frame's background
  plane: far surfaces move little between nearby views, so a plane near their depth lines them up.
Measured: docs/research-log.md, The blend at the prior.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras, check_shape
from insertnerf_cli.cameras.rays import Rays, rays_for_image
from insertnerf_cli.model import EncodedViews
from insertnerf_cli.model.aggregate import angular_prior, weighted_moments
from insertnerf_cli.model.projection import Projected, project_samples
from insertnerf_cli.rendering.image_renderer import ImageOutput
from insertnerf_cli.sfm.depth_prior import PriorOptions

# Pixels reprojected per pass: [V, 3 + 3 + 4 + 1, P] floats (colours, finer colours, ray_diff, mask) for 10 views
# stay near 30 MB.
PIXELS_PER_PASS = 65536


@dataclass(frozen=True)
class BlendOptions:
    """The rules of the blend at the prior.

    Attributes:
        views: the blend and the agreement weigh the lumigraph weights of this many views nearest in angle.
        window_fraction: the patch the variance is averaged over, as a fraction of the long side (7 px at 256).
        margin: a filled pixel's blend weighs (v_render / (margin v_prior)) ** fill_power against the frame's
            colour (v: patch variance): half where the references agree ``margin`` times better at the prior.
        fill_power: how steeply a filled pixel's share rises through one half (nearly all or nothing a factor 2
            either side at 3).
        mix_power: a splatted pixel's blend weighs (v_render / v_prior) ** mix_power against the frame's colour.
        unseen_cost: the variance of a point fewer than two references see: above any of colours in [0, 1]
            (3 channels x 1/4), so such a point never wins, and a patch holding a few still can.
        smooth_span: a filled pixel whose fill could come from splats lying within this fraction of the nearest
            one's depth sits on one smooth surface and is mixed like a splat.
        feather_fraction: the window over which a splat's mix fades into the rule around it, as a fraction of the
            long side (5 px at 256); an isolated disc has no rim.
        background_quantile: the frame's background plane lies at this quantile of its prior's depths.
        background_margin, background_power: a bare pixel's share of the blend at that plane, as margin and
            fill_power for a filled pixel; high, so that the plane is taken only where it clearly agrees better.
    """

    views: int = 8
    window_fraction: float = 7 / 256
    margin: float = 1.5
    fill_power: float = 3.0
    mix_power: float = 2.0
    unseen_cost: float = 1.0
    smooth_span: float = 0.15
    feather_fraction: float = 5 / 256
    background_quantile: float = 0.9
    background_margin: float = 3.0
    background_power: float = 3.0

    def __post_init__(self) -> None:
        if self.views < 1 or self.window_fraction <= 0 or self.feather_fraction <= 0 or self.margin <= 0 \
                or not 0.0 < self.background_quantile <= 1.0:
            raise ValueError(f"invalid blend options {self}")


def reference_colours(encoded: EncodedViews, rays: Rays, depth: Tensor, finer: bool = True) -> Projected:
    """What each reference sees of R rays' points at camera-z ``depth`` [R] (the rays' directions have z = 1;
    NaN: nothing there, masked out): colours [V, 3, R] at the frame's size, finer ones where encoded holds them
    and ``finer`` asks (only a blend reads them), mask [V, 1, R] (0 also where a reference's occlusion map, when
    encoded holds them, hides the point), ray_diff [V, 4, R]."""
    known = torch.isfinite(depth)
    points = rays.origins + rays.directions * torch.where(known, depth, torch.ones_like(depth))[:, None]  # [R, 3]
    # A reference whose own points show a nearer surface in front of the point does not see it (occlusion_maps).
    seen = project_samples(encoded, points[:, None], rays.directions, finer=finer, features=False).unoccluded()
    return Projected((), seen.colours, seen.mask * known.to(seen.mask)[None, None], seen.ray_diff, seen.finer)


def variance(seen: Projected, weights: Tensor | None = None, options: BlendOptions = BlendOptions()) -> Tensor:
    """[R] the references' summed RGB variance at each point under the lumigraph weights [V, 1, R] of the
    ``options.views`` views nearest in angle (``weights``: those, computed already); ``options.unseen_cost``
    where fewer than two views see it."""
    if weights is None:
        weights = angular_prior(seen.ray_diff, seen.mask, options.views)
    _, var = weighted_moments(seen.colours, weights)  # [1, 3, R]
    lonely = seen.mask.sum(dim=(0, 1)) < 2
    return torch.where(lonely, torch.full_like(var[0, 0], options.unseen_cost), var.sum(dim=1)[0])


def blend(seen: Projected, weights: Tensor | None = None, options: BlendOptions = BlendOptions()) -> Tensor:
    """[R, 3] the lumigraph blend of the ``options.views`` references nearest in angle (finer colours where held)
    under their weights [V, 1, R] (``weights``: those, computed already)."""
    if weights is None:
        weights = angular_prior(seen.ray_diff, seen.mask, options.views)
    return (seen.blend_colours * weights).sum(dim=0).T


def patch_mean(cost: Tensor, size: tuple[int, int], fraction: float) -> Tensor:
    """[R] per-pixel ``cost`` [R] averaged over a square patch of ``fraction`` of the long side (odd, centred;
    the pixels inside the frame only)."""
    window = max(1, round(fraction * max(size))) | 1
    # A patch clipped by the frame is still a rectangle, so its mean is the mean over its rows of each row's mean:
    # two 1-D pools cost 2 w per pixel, not w^2 (the same values up to float rounding).
    rows = F.avg_pool2d(cost.reshape(1, 1, *size), (1, window), stride=1, padding=(0, window // 2),
                        count_include_pad=False)
    return F.avg_pool2d(rows, (window, 1), stride=1, padding=(window // 2, 0), count_include_pad=False).reshape(-1)


def blend_at_prior(frame: ImageOutput, encoded: EncodedViews, camera: Cameras, prior: Tensor, far: float,
                   splatted: Tensor | None = None, background: bool = False, options: BlendOptions = BlendOptions(),
                   prior_options: PriorOptions = PriorOptions()) -> ImageOutput:
    """``frame`` with its references' blend at the ``prior`` depth [H, W] (NaN: none) given where they agree there:
    each pixel's share of the blend rises steeply (``options.fill_power``) through one half where its references
    agree ``options.margin`` times better at the prior than at the frame's own depth; near the pixels ``splatted``
    [H, W] (bool: a prior point's own disc; None: none) and the fill between splats on one smooth surface
    (smooth_fill, whose reach ``prior_options`` gives), that share moves to a splat's gentler mix_share by the part
    of a feather window they cover. Depth: the prior where the blend's share passes one half; opacity kept. A prior
    past ``far``, the bound the frame was rendered within, is left out: depth files sized for it hold every pixel.
    ``background`` (object-centric captures): the pixels without a prior mix in the blend at the frame's background
    plane (background_plane) the same way."""
    height, width = camera.height, camera.width
    check_shape("prior", prior, (height, width))
    param = encoded.images
    camera = camera.to(device=param.device, dtype=param.dtype)
    prior_flat, rendered = prior.to(param).reshape(-1), frame.depth.to(param).reshape(-1)  # [R] each
    ones = param.new_ones(1)
    rays = rays_for_image(camera, ones, ones)
    size = (height, width)
    window = options.window_fraction
    at_prior = looked_up(encoded, rays, prior_flat, options=options)
    # The rendered depth is only tested, never blended at: no finer colours.
    agree_render = patch_mean(looked_up(encoded, rays, rendered, colours=False, options=options).variance, size,
                              window)
    agree_prior, colours, target = patch_mean(at_prior.variance, size, window), at_prior.colours, prior_flat
    # A pixel whose own prior point fewer than two references see has no blend to speak of (none: black), however
    # well its patch agrees.
    usable = (prior_flat <= far) & at_prior.seen_twice  # [R]; NaN: False
    fill_share = mix_share(agree_prior, agree_render, options.fill_power, options.margin)
    share = torch.where(usable, fill_share, 0.0)  # [R] the blend's share
    if splatted is not None:
        check_shape("splatted", splatted, (height, width))
        mixed = splatted.to(prior.device) | smooth_fill(prior, splatted, options, prior_options)  # [H, W]
        splat_share = mix_share(agree_prior, agree_render, options.mix_power)
        share = torch.where(usable, feathered(share, splat_share, mixed, options), share)
    bare = ~torch.isfinite(prior_flat)
    plane = background_plane(prior, far, options) if background else None
    if plane is not None and bool(bare.any()):
        at_plane = looked_up(encoded, rays, torch.full_like(prior_flat, plane), options=options)
        agree_plane = patch_mean(at_plane.variance, size, window)
        plane_share = mix_share(agree_plane, agree_render, options.background_power, options.background_margin)
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


def looked_up(encoded: EncodedViews, rays: Rays, depth: Tensor, colours: bool = True,
              options: BlendOptions = BlendOptions()) -> LookedUp:
    """The references at camera-z ``depth`` [R] along R ``rays`` (NaN: nothing there), PIXELS_PER_PASS at a time;
    ``colours`` False: the variance alone (LookedUp.colours empty, [R, 0])."""
    parts = []
    for start in range(0, len(rays), PIXELS_PER_PASS):
        seen = reference_colours(encoded, rays[start:start + PIXELS_PER_PASS], depth[start:start + PIXELS_PER_PASS],
                                 finer=colours)
        # One set of lumigraph weights serves the variance and the blend.
        weights = angular_prior(seen.ray_diff, seen.mask, options.views)  # [V, 1, R]
        blended = blend(seen, weights, options) if colours else seen.colours.new_zeros(seen.colours.shape[-1], 0)
        parts.append((variance(seen, weights, options), blended, seen.mask.sum(dim=(0, 1)) >= 2))
    return LookedUp(*(torch.cat(p) for p in zip(*parts)))


def background_plane(prior: Tensor, far: float, options: BlendOptions = BlendOptions()) -> float | None:
    """The camera-z depth [scalar] of a frame's background: the ``options.background_quantile`` of its ``prior``
    [H, W] depths within ``far``; None where it has none."""
    depths = prior[torch.isfinite(prior) & (prior <= far)].double()
    if depths.numel() == 0:
        return None
    rank = min(depths.numel(), max(1, round(options.background_quantile * depths.numel())))
    return float(depths.kthvalue(rank).values)


def feathered(hard: Tensor, mix: Tensor, mixed: Tensor, options: BlendOptions = BlendOptions()) -> Tensor:
    """[R] the blend's share: ``hard`` [R] (the all-or-nothing rule's) moved toward ``mix`` [R] by the part of each
    pixel's ``options.feather_fraction`` window that the pixels ``mixed`` [H, W] (bool) cover."""
    cover = patch_mean(mixed.to(hard).reshape(-1), (mixed.shape[0], mixed.shape[1]), options.feather_fraction)  # [R]
    return torch.lerp(hard, mix, cover)


def smooth_fill(prior: Tensor, splatted: Tensor, options: BlendOptions = BlendOptions(),
                prior_options: PriorOptions = PriorOptions()) -> Tensor:
    """[H, W] bool: the filled pixels of ``prior`` [H, W] (NaN: none) whose splats within the fill's reach (a square
    of 2 reach + 1 px, ``prior_options.fill_reach``; ``splatted`` [H, W]: a point's own disc) lie no more than
    ``options.smooth_span`` of the nearest one's depth behind it: every point the fill could have taken lies on one
    surface."""
    check_shape("splatted", splatted, tuple(prior.shape))
    window = 2 * prior_options.fill_reach(max(prior.shape)) + 1
    depth, splats = prior.double(), splatted.to(prior.device)  # [H, W] each

    def largest(values: Tensor) -> Tensor:  # [H, W] the largest of ``values`` on the splats in each window
        on_splats = torch.where(splats, values, -torch.inf)  # [H, W]
        # A square's maximum is the maximum over its rows of each row's.
        return window_max(window_max(on_splats, window, dim=1), window, dim=0)

    nearest, farthest = -largest(-depth), largest(depth)
    filled = torch.isfinite(prior) & ~splats
    return filled & torch.isfinite(nearest) & (farthest <= nearest * (1.0 + options.smooth_span))


def window_max(values: Tensor, window: int, dim: int) -> Tensor:
    """``values`` with each entry replaced by the largest within ``window`` (odd) entries centred on it along
    ``dim``, the window cut at the ends. Maxima over 1, 2, 4, ... entries, each the larger of two of the last, give
    any window as the larger of two overlapping powers of two: log2 w passes instead of max_pool's w comparisons
    per entry, with the same values."""
    if window % 2 != 1:
        raise ValueError(f"window_max needs an odd window, got {window}")
    half = window // 2
    moved = values.movedim(dim, -1)
    pad = moved.new_full((*moved.shape[:-1], half), -torch.inf)
    span, table = 1, torch.cat([pad, moved, pad], dim=-1)  # table[..., j]: the largest of span entries from j
    while 2 * span <= window:
        table = torch.maximum(table[..., :-span], table[..., span:])
        span *= 2
    length = moved.shape[-1]
    return torch.maximum(table[..., :length], table[..., window - span:window - span + length]).movedim(-1, dim)


def mix_share(at_prior: Tensor, at_render: Tensor, power: float, margin: float = 1.0) -> Tensor:
    """[R] the blend's share of a pixel's colour from the references' patch variances [R] at the prior and at the
    rendered depth: at_render ** p / (at_render ** p + (margin at_prior) ** p), p = ``power``; 0 (the frame's
    colour) where both are 0."""
    render_term, prior_term = at_render ** power, (margin * at_prior) ** power
    total = render_term + prior_term
    share = render_term / total.clamp(min=torch.finfo(total.dtype).tiny)
    return torch.where(total > 0, share, torch.zeros_like(total))
