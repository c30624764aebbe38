"""Probe: occlusion tested against each reference's own SfM points (issue 27, round 21).

Round 15's bench/visibility_probe.py tested a sample against each reference's *rendered* depth map and lost on
beer, whose references' renders held no railing to occlude with. COLMAP knows better what a reference sees: the
points in whose tracks it stands. Here each reference's depth map is made from those points alone (the points
that two views outside the held-out one observe and the reference does), splatted and filled by
depth_prior.prior_depth at LOW px; pixels no point reaches count as infinitely far (visible). A sample then counts
as seen by a reference only where its depth there is within (1 + tol) of that map, in the colour prior and the
cue (colour:TOL) or also in the aggregators' mask (all:TOL), as in visibility_probe. The frame itself is the
library's render: its SfM prior for the fine samples, its raised far bound and its blend at the SfM depth.

    OMP_NUM_THREADS=1 python3 bench/sfm_visibility_probe.py --variants off,colour:0.15,all:0.3 --captures room \
        --views 3,10
"""
from __future__ import annotations

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import visibility_probe as vp  # noqa: E402
from insertnerf_cli.depth_prior import prior_depth  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer  # noqa: E402


def reference_points_depth(renderer: ViewRenderer, index: int, exclude: list[int]) -> torch.Tensor:
    """[1, h, w] depth map of reference ``index`` from the SfM points it observes (FAR where none reaches)."""
    reach = vp.SETTINGS["reach"]
    key = (str(renderer.scene.root), index, tuple(sorted(exclude)), reach)
    if key not in vp.STATE["cache"]:
        scene = renderer.scene
        camera = scene.cameras.subset([index]).rescale(*scene.size_for(vp.LOW))
        allowed = [i for i in range(len(scene)) if i not in set(exclude)]
        points = scene.points.seen_from(allowed, near=[index])
        depth = prior_depth(points, camera, None if reach is None else reach / vp.LOW) if len(points) \
            else torch.full((camera.height, camera.width), vp.FAR)
        vp.STATE["cache"][key] = torch.nan_to_num(depth, nan=vp.FAR).float()[None]
    return vp.STATE["cache"][key]


def render(self: ViewRenderer, camera, near: float, far: float, exclude: list[int], views: int | None = None):
    """ViewRenderer.render with the references' point maps set for observe (in the encoding's sorted order)."""
    refs = self.references(camera.c2w[0], exclude, views)
    usable = vp.SETTINGS["mode"] != "off" and self.scene.points is not None
    vp.STATE["maps"] = torch.stack([reference_points_depth(self, r, exclude) for r in sorted(refs)]) if usable \
        else None
    try:  # the library's own render (its SfM prior, raised far bound and blend), which picks the same references
        return vp.LIBRARY_RENDER(self, camera, near, far, exclude, views)
    finally:
        vp.STATE["maps"] = None


if __name__ == "__main__":
    vp.main(render, __doc__)
