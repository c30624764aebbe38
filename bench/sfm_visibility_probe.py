"""Probe: occlusion tested against each reference's own SfM points (issue 27, rounds 21 and 32).

Round 15's bench/visibility_probe.py tested a sample against each reference's *rendered* depth map and lost on
beer, whose references' renders held no railing to occlude with. COLMAP knows better what a reference sees: the
points in whose tracks it stands. Here each reference's depth map is made from those points alone (the points
that OBS views outside the held-out one observe and the reference does), splatted and filled by
depth_prior.prior_depth at LOW px; pixels no point reaches count as infinitely far (visible). A sample then counts
as seen by a reference only where its depth there is within (1 + tol) of that map, in the colour prior and the
cue (colour:...) or also in the aggregators' mask (all:...), as in visibility_probe. The frame itself is the
library's render: its SfM prior for the fine samples, its raised far bound and its blend at the SfM depth.

A variant is MODE:TOL[:REACH[:OBS[:VIS[:DEG]]]]: REACH the maps' fill reach in px at their 128 px (default:
prior_depth's), OBS the observers a map's point needs among the views not held out (default 2), VIS the views
that must pass for the test to apply to a sample (else every view keeps its say; default 1), DEG views nearer the
query ray than this many degrees are never masked (default 0). Round 32's probe table: all:0.3::3:2:DEG. Since
round 32 the library tests occlusion itself (model/occlusion.py, with a gate in parallax instead of degrees);
every variant here runs with the library's own test off, and the variant ``library`` runs it as shipped.

    OMP_NUM_THREADS=1 python3 bench/sfm_visibility_probe.py --variants off,colour:0.15,all:0.3 --captures room \
        --views 3,10
    OMP_NUM_THREADS=1 python3 bench/sfm_visibility_probe.py --variants off,all:0.3::3:2,all:0.3::3:2:3,library \
        --captures mold_gold_cape,room --views 3,10
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import visibility_probe as vp  # noqa: E402
from insertnerf_cli.depth_prior import prior_depth  # noqa: E402
from insertnerf_cli.model.projection import ray_angle  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer  # noqa: E402

EXTRA = {"observers": 2, "visible": 1, "degrees": 0.0, "library": False}
LAST: dict = {}  # the last projection of observe, for the angle gate
LIBRARY_PROJECT = vp.project_samples
LIBRARY_VISIBLE = vp.visible


def reference_points_depth(renderer: ViewRenderer, index: int, exclude: list[int]) -> torch.Tensor:
    """[1, h, w] depth map of reference ``index`` from the SfM points it observes (FAR where none reaches)."""
    reach = vp.SETTINGS["reach"]
    key = (str(renderer.scene.root), index, tuple(sorted(exclude)), reach, EXTRA["observers"])
    if key not in vp.STATE["cache"]:
        scene = renderer.scene
        camera = scene.cameras.subset([index]).rescale(*scene.size_for(vp.LOW))
        allowed = [i for i in range(len(scene)) if i not in set(exclude)]
        keep = (scene.points.observers(allowed) >= EXTRA["observers"]) & (scene.points.observers([index]) >= 1)
        points = scene.points.xyz[keep]
        depth = prior_depth(points, camera, None if reach is None else reach / vp.LOW) if len(points) \
            else torch.full((camera.height, camera.width), vp.FAR)
        vp.STATE["cache"][key] = torch.nan_to_num(depth, nan=vp.FAR).float()[None]
    return vp.STATE["cache"][key]


def project_samples(*args, **kwargs):
    LAST["seen"] = LIBRARY_PROJECT(*args, **kwargs)
    return LAST["seen"]


def visible(encoded, points: torch.Tensor) -> torch.Tensor:
    """visibility_probe.visible with the angle gate and the fewest passing views (EXTRA)."""
    vis = LIBRARY_VISIBLE(encoded, points)
    if EXTRA["degrees"] > 0:
        near = ray_angle(LAST["seen"].ray_diff) < math.radians(EXTRA["degrees"])
        vis = torch.where(near, torch.ones_like(vis), vis)
    if EXTRA["visible"] > 1:  # too few pass: none does, and observe gives every view its say
        # Counted before observe's mask, as round 32's table was (the library counts the masked views).
        vis = torch.where(vis.sum(0, keepdim=True) < EXTRA["visible"], torch.zeros_like(vis), vis)
    return vis


def render(self: ViewRenderer, camera, near: float, far: float, exclude: list[int], views: int | None = None):
    """ViewRenderer.render with the references' point maps set for observe (in the encoding's sorted order)."""
    refs = self.references(camera.c2w[0], exclude, views)
    usable = vp.SETTINGS["mode"] not in ("off", "library") and self.scene.points is not None
    vp.STATE["maps"] = torch.stack([reference_points_depth(self, r, exclude) for r in sorted(refs)]) if usable \
        else None
    self.occlusion = EXTRA["library"] and self.scene.points is not None and self.scene.points.observed is not None
    try:  # the library's own render (its SfM prior, raised far bound and blend), which picks the same references
        return vp.LIBRARY_RENDER(self, camera, near, far, exclude, views)
    finally:
        vp.STATE["maps"] = None


def set_variant(variant: str) -> None:
    parts = variant.split(":") + [""] * 6
    mode, tol, reach, observers, visible_views, degrees = parts[:6]
    vp.SETTINGS.update(mode=mode, tol=float(tol or 0.15), reach=int(reach) if reach else None)
    EXTRA.update(observers=int(observers or 2), visible=int(visible_views or 1), degrees=float(degrees or 0.0),
                 library=mode == "library")


if __name__ == "__main__":
    vp.project_samples = project_samples
    vp.visible = visible
    vp.set_variant = set_variant
    vp.main(render, __doc__)
