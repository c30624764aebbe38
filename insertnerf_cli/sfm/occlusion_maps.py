"""Each reference view's nearer surfaces from its own SfM points: the maps model.occlusion tests samples against.

A view's map splats and fills (depth_prior.prior_depth) the points it observes itself among those that enough of
the views a frame may draw from observe (depth_prior.well_tracked, counted once per pool by the caller): a two-view
track errs most in depth, and a point wrongly near would hide a surface the view sees (measured:
docs/research-log.md, Occlusion maps).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.model.occlusion import Occlusion
from insertnerf_cli.scenes.points import ScenePoints
from insertnerf_cli.sfm.depth_prior import PriorOptions, prior_depth


@dataclass(frozen=True)
class OcclusionOptions:
    """How the references' occlusion maps are made and tested (model.occlusion.visible).

    Attributes:
        map_size: the maps' long side in px; a sample is tested against the nearest map pixel, so the maps'
            splats and fill stay as coarse as they were measured at this size.
        tolerance: a sample farther from a view than its map's depth times 1 + tolerance is hidden from it.
        near_parallax: views whose ray through a sample lies within this parallax of the query ray are never
            masked (the angle times the view's focal length over its long side: a longer lens shifts a depth error
            by more of its frame per degree).
        min_visible: where fewer views than this pass the test, every view that sees the sample keeps it.
    """

    map_size: int = 128
    tolerance: float = 0.3
    near_parallax: float = 0.12
    min_visible: int = 2

    def __post_init__(self) -> None:
        if self.map_size < 1 or self.tolerance < 0 or self.near_parallax < 0 or self.min_visible < 1:
            raise ValueError(f"invalid occlusion options {self}")


def reference_map(points: ScenePoints, camera: Cameras, view: int, tracked: torch.Tensor,
                  prior: PriorOptions = PriorOptions()) -> torch.Tensor:
    """[1, h, w] camera-z depth of the nearest surface ``view`` sees, for ``camera`` (1, that view's at the map's
    size): the points it observes among the ``tracked`` ones ([P] bool, depth_prior.well_tracked of the frame's
    usable views), drawn as ``prior`` draws a frame's prior; inf where none."""
    keep = tracked & (points.observers([view]) >= 1)
    if not bool(keep.any()):
        return torch.full((1, camera.height, camera.width), math.inf)
    depth = prior_depth(points.xyz[keep], camera, prior).float()
    return torch.nan_to_num(depth, nan=math.inf)[None]


def near_angle(cameras: Cameras, options: OcclusionOptions = OcclusionOptions()) -> torch.Tensor:
    """[V] the angle (radians) within which a view's rays are never masked: ``options.near_parallax`` over its
    focal length per long side."""
    focal = cameras.K[:, 0, 0].float() / max(cameras.height, cameras.width)
    return options.near_parallax / focal


def occlusion(maps: Sequence[torch.Tensor], cameras: Cameras,
              options: OcclusionOptions = OcclusionOptions()) -> Occlusion:
    """The Occlusion of V views from their reference_map()s (in ``cameras``' order)."""
    return Occlusion(torch.stack(list(maps)), near_angle(cameras, options), options.tolerance, options.min_visible)
