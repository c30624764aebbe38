"""Probe: occlusion tested against each reference's own depth map (issue 27, round 15; NeuRay's idea, a shadow map).

Round 15 found beer's worst views spoilt by references that see a nearer surface (the staircase railing) where the
target sees a wall. Here every reference view first gets a depth map of its own: rendered by the same generator
at LOW px from its nearest non-held-out views (cached, once per reference). A sample then counts as seen by a
reference only where its depth in that view is at most (1 + tol) x the view's depth map there (maps whose opacity
is under OPAQUE count as infinitely far). Where no reference passes, all keep their say. The test changes, per
variant:

- colour: which views the colour prior and the photo-consistency cue weigh (the K nearest *visible* views);
- all: also the mask the generator's aggregators see (geometry), as if the occluded views did not see the sample.

InsertNeRF.observe and ViewRenderer.render are patched in this process only (the shipped weights).

    OMP_NUM_THREADS=1 python3 bench/visibility_probe.py --variants off,colour:0.15,all:0.15 --captures beer \
        --views 3,10
"""
from __future__ import annotations

import sys
from pathlib import Path

import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.model.aggregate import angular_prior, reweigh  # noqa: E402
from insertnerf_cli.model.consistency import colour_variance  # noqa: E402
from insertnerf_cli.model.insertnerf import InsertNeRF  # noqa: E402
from insertnerf_cli.model.projection import Projected, pixel_coordinates, project_samples, ray_angle  # noqa: E402
from insertnerf_cli.model.types import SampleFeatures  # noqa: E402
from insertnerf_cli.render import render_image  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer  # noqa: E402
from insertnerf_cli.views import nearest_views  # noqa: E402
from view_set_probe import variants_main  # noqa: E402

LOW, OPAQUE, FAR = 128, 0.5, 1e6  # depth-map long side (px), opacity of a surface, depth of an empty pixel
SETTINGS = {"mode": "off", "tol": 0.15, "reach": None}
STATE: dict = {"maps": None, "cache": {}}
LIBRARY_RENDER = ViewRenderer.render  # before main() patches them
LIBRARY_OBSERVE = InsertNeRF.observe


def reference_depth(renderer: ViewRenderer, index: int, exclude: list[int]) -> torch.Tensor:
    """[1, h, w] depth map of reference ``index`` from its own nearest views (never one in ``exclude``)."""
    key = (str(renderer.scene.root), index, renderer.k, renderer.size)
    if key not in STATE["cache"]:
        scene = renderer.scene
        camera = scene.cameras.subset([index]).rescale(*scene.size_for(LOW))
        refs = nearest_views(camera.c2w[0], scene.cameras.c2w, renderer.k, renderer.method,
                             exclude=[*exclude, index])
        out = render_image(renderer.model, renderer._encoded(refs), camera, float(scene.near[index]),
                           float(scene.far[index]), renderer.chunk, renderer.shortcuts)
        STATE["cache"][key] = torch.where(out.opacity > OPAQUE, out.depth, torch.full_like(out.depth, FAR))[None]
    return STATE["cache"][key]


def render(self: ViewRenderer, camera, near: float, far: float, exclude: list[int], views: int | None = None):
    """ViewRenderer.render with the references' depth maps set for observe (in the encoding's sorted order). The
    references' own depth maps (reference_depth) are rendered without the SfM prior, as in round 15."""
    refs = self.references(camera.c2w[0], exclude, views)
    STATE["maps"] = None  # the depth maps' own renders test nothing
    maps = torch.stack([reference_depth(self, r, exclude) for r in sorted(refs)]) if SETTINGS["mode"] != "off" \
        else None
    STATE["maps"] = maps
    try:  # the library's own render (its SfM prior, the far bound that raises), which picks the same references
        return LIBRARY_RENDER(self, camera, near, far, exclude, views)
    finally:
        STATE["maps"] = None


def visible(encoded, points: torch.Tensor) -> torch.Tensor:
    """[V, 1, P] 1 where a sample's depth in a view is within (1 + tol) of the view's depth map there."""
    uv, depth = pixel_coordinates(encoded.projection.to(points), points.reshape(-1, 3).T)  # [V, 2 | 1, P]
    scale = torch.tensor([2.0 / encoded.width, 2.0 / encoded.height], dtype=uv.dtype, device=uv.device)[:, None]
    grid = (uv * scale - 1.0).transpose(1, 2)[:, None]  # [V, 1, P, 2]
    maps = STATE["maps"].to(points)  # [V, 1, h, w]
    surface = F.grid_sample(maps, grid, mode="nearest", padding_mode="border", align_corners=False)[:, :, 0]
    return (depth <= surface * (1.0 + SETTINGS["tol"])).to(points.dtype)


def observe(self, encoded, rays, samples, colour=True, variance=False):
    """InsertNeRF.observe with the references' visibility in the colour and cue weights (and the mask: all); the
    library's own where no maps are set (variant off, the maps' own renders)."""
    if STATE["maps"] is None:
        return LIBRARY_OBSERVE(self, encoded, rays, samples, colour, variance)
    points = samples.points(rays)
    rays_n, samples_n = points.shape[:2]
    seen = project_samples(encoded, points, rays.directions, finer=colour)
    vis = visible(encoded, points) * seen.mask
    vis = torch.where(vis.sum(0, keepdim=True) >= 1, vis, seen.mask)  # none passes: all keep their say
    # Carried through nearest_in_angle's per-sample choice as a fourth colour channel.
    seen = Projected(seen.features, torch.cat([seen.colours, vis], 1), seen.mask, seen.ray_diff, seen.finer)
    if self.config.sample_views:
        seen = seen.nearest_in_angle(self.config.sample_views)
    colours, mask = seen.colours[:, :3], seen.colours[:, 3:]
    seen = Projected(seen.features, colours, mask if SETTINGS["mode"] == "all" else seen.mask, seen.ray_diff,
                     seen.finer)
    angle = ray_angle(seen.ray_diff)
    cost = None
    if variance:
        weights = angular_prior(seen.ray_diff, mask, self.config.consistency_views, angle)
        cost = colour_variance(seen.colours, mask, weights, samples_n)
    inputs = [*seen.features[:-1], torch.cat([seen.features[-1], seen.colours], dim=1)]
    descriptors, dynamics = zip(*(agg(f, seen.mask, seen.ray_diff) for agg, f in zip(self.aggregators, inputs)))
    dynamic = torch.stack(dynamics).mean(dim=0)
    if colour and self.config.colour_prior_views:
        dynamic = reweigh(dynamic, angular_prior(seen.ray_diff, mask, self.config.colour_prior_views, angle))
    return SampleFeatures(points=points, conds=tuple(d.reshape(rays_n, samples_n, -1) for d in descriptors),
                          dynamic=dynamic, colours=seen.blend_colours, colour_variance=cost)


def set_variant(variant: str) -> None:
    mode, _, rest = variant.partition(":")
    tol, _, reach = rest.partition(":")
    SETTINGS.update(mode=mode, tol=float(tol or 0.15), reach=int(reach) if reach else None)


def main(patched_render=render, description: str = __doc__) -> None:
    """The probe's command line, with ``patched_render`` (a ViewRenderer.render that sets STATE["maps"])."""
    def patch() -> None:
        InsertNeRF.observe = observe
        ViewRenderer.render = patched_render

    variants_main(description, "off,colour:0.15", set_variant, patch,
                  "off, colour:TOL or all:TOL, comma-separated; sfm_visibility_probe also takes MODE:TOL:REACH (the "
                  "maps' fill reach in px at their 128 px)")


if __name__ == "__main__":
    main()
