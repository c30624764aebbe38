"""Each reference view's nearer surfaces from its own SfM points: the maps model.occlusion tests samples against.

A view's map splats and fills (depth_prior.prior_depth) the points it observes itself that WELL_TRACKED of the
views a frame may draw from observe: a two-view track errs most in depth, and a point wrongly near would hide a
surface the view sees (round 32's probe: room -0.8 dB at 10 views with two-view tracks in the maps, -0.4 without,
before the near-parallax guard).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Sequence

import torch

from .cameras import Cameras
from .depth_prior import WELL_TRACKED, prior_depth
from .model.occlusion import NEAR_PARALLAX, Occlusion

if TYPE_CHECKING:
    from .scenes.points import ScenePoints

# The maps' long side in pixels: a sample is tested against the nearest map pixel, and 128 px keeps the maps'
# splats (2 px) and fill (6 px) as coarse as the probes measured them (bench/sfm_visibility_probe.py).
MAP_SIZE = 128


def reference_map(points: "ScenePoints", camera: Cameras, view: int, pool: Sequence[int]) -> torch.Tensor:
    """[1, h, w] camera-z depth of the nearest surface ``view`` sees, for ``camera`` (1, that view's, at any size:
    it is rescaled to MAP_SIZE): the points it observes that WELL_TRACKED of ``pool`` observe; inf where none."""
    size = _map_size(camera)
    small = camera.rescale(*size)
    keep = (points.observers(list(pool)) >= WELL_TRACKED) & (points.observers([view]) >= 1)
    if not bool(keep.any()):
        return torch.full((1, *size), math.inf)
    depth = prior_depth(points.xyz[keep], small).float()
    return torch.nan_to_num(depth, nan=math.inf)[None]


def near_angle(cameras: Cameras) -> torch.Tensor:
    """[V] the angle (radians) within which a view's rays are never masked: NEAR_PARALLAX over its focal length
    per long side (a longer lens shifts a depth error by more of its frame per degree)."""
    focal = cameras.K[:, 0, 0].float() / max(cameras.height, cameras.width)
    return NEAR_PARALLAX / focal


def occlusion(maps: Sequence[torch.Tensor], cameras: Cameras) -> Occlusion:
    """The Occlusion of V views from their reference_map()s (in ``cameras``' order)."""
    return Occlusion(torch.stack(list(maps)), near_angle(cameras))


def _map_size(camera: Cameras) -> tuple[int, int]:
    if max(camera.height, camera.width) <= MAP_SIZE:
        return camera.height, camera.width
    scale = MAP_SIZE / max(camera.height, camera.width)
    return max(1, round(camera.height * scale)), max(1, round(camera.width * scale))
