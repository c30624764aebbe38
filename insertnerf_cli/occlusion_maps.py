"""Each reference view's nearer surfaces from its own SfM points: the maps model.occlusion tests samples against.

A view's map splats and fills (depth_prior.prior_depth) the points it observes itself that WELL_TRACKED of the
views a frame may draw from observe (depth_prior.well_tracked, counted once per pool by the caller): a two-view
track errs most in depth, and a point wrongly near would hide a surface the view sees (round 32's probe: room
-0.8 dB at 10 views with two-view tracks in the maps, -0.4 without, before the near-parallax guard).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Sequence

import torch

from .cameras import Cameras
from .depth_prior import prior_depth
from .model.occlusion import NEAR_PARALLAX, Occlusion

if TYPE_CHECKING:
    from .scenes.points import ScenePoints

# The maps' long side in pixels: a sample is tested against the nearest map pixel, and 128 px keeps the maps'
# splats (2 px) and fill (6 px) as coarse as the probes measured them (bench/sfm_visibility_probe.py).
MAP_SIZE = 128


def reference_map(points: "ScenePoints", camera: Cameras, view: int, tracked: torch.Tensor) -> torch.Tensor:
    """[1, h, w] camera-z depth of the nearest surface ``view`` sees, for ``camera`` (1, that view's at the map's
    size, MAP_SIZE on the long side): the points it observes among the ``tracked`` ones ([P] bool,
    depth_prior.well_tracked of the frame's usable views); inf where none."""
    keep = tracked & (points.observers([view]) >= 1)
    if not bool(keep.any()):
        return torch.full((1, camera.height, camera.width), math.inf)
    depth = prior_depth(points.xyz[keep], camera).float()
    return torch.nan_to_num(depth, nan=math.inf)[None]


def near_angle(cameras: Cameras) -> torch.Tensor:
    """[V] the angle (radians) within which a view's rays are never masked: NEAR_PARALLAX over its focal length
    per long side (a longer lens shifts a depth error by more of its frame per degree)."""
    focal = cameras.K[:, 0, 0].float() / max(cameras.height, cameras.width)
    return NEAR_PARALLAX / focal


def occlusion(maps: Sequence[torch.Tensor], cameras: Cameras) -> Occlusion:
    """The Occlusion of V views from their reference_map()s (in ``cameras``' order)."""
    return Occlusion(torch.stack(list(maps)), near_angle(cameras))

