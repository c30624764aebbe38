"""Scene geometry from cameras alone: focus point, layout, and fallback near/far bounds.

All functions take OpenCV cameras (``Cameras``) and work in float64.
"""
from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.scenes.base import Layout

# Forward-facing captures keep every optical axis within this angle of the mean axis (LLFF scenes stay
# under ~25 deg); object-centric arcs and orbits spread wider.
FORWARD_MAX_ANGLE_DEG = 45.0
# A NeRF-Synthetic camera 4 units from the object uses near/far 2/6: half and one and a half times the distance.
OBJECT_NEAR_RATIO, OBJECT_FAR_RATIO = 0.5, 1.5
# Forward-facing scenes without depth information: a deliberately wide slab around the focus depth.
FORWARD_NEAR_RATIO, FORWARD_FAR_RATIO = 0.25, 4.0
# LLFF's bounds are the 0.1 and 99.9 percentiles of the depths of the points a view sees.
POINT_PERCENTILES = (0.1, 99.9)
# Above this condition number the optical axes are too close to parallel for a least-squares focus point.
_MAX_FOCUS_CONDITION = 1e6


def focus_point(cameras: Cameras) -> Tensor | None:
    """Least-squares point nearest to every optical axis [3], or None when the axes are (nearly) parallel.

    Minimises sum_i |(I - d_i d_i^T)(p - o_i)|^2 over p, for centres o_i and unit axes d_i.
    """
    centers = cameras.centers.to(torch.float64)  # [N, 3]
    axes = torch.nn.functional.normalize(cameras.forward.to(torch.float64), dim=-1)  # [N, 3]
    eye = torch.eye(3, dtype=torch.float64, device=centers.device)
    proj = eye - axes[:, :, None] * axes[:, None, :]  # [N, 3, 3] projectors orthogonal to each axis
    A = proj.sum(0)
    b = (proj @ centers[:, :, None]).sum(0)[:, 0]
    if len(cameras) < 2 or torch.linalg.cond(A) > _MAX_FOCUS_CONDITION:
        return None
    return torch.linalg.solve(A, b)


def axis_spread_deg(cameras: Cameras) -> float:
    """Largest angle in degrees between an optical axis and the mean optical axis (180 if they cancel out)."""
    axes = torch.nn.functional.normalize(cameras.forward.to(torch.float64), dim=-1)
    mean = axes.mean(0)
    if mean.norm() < 1e-6:
        return 180.0
    cos = (axes @ (mean / mean.norm())).clamp(-1.0, 1.0)
    return math.degrees(float(torch.acos(cos.min())))


def detect_layout(cameras: Cameras) -> Layout:
    """"forward" when every optical axis stays within FORWARD_MAX_ANGLE_DEG of the mean axis, else "object"."""
    return "forward" if len(cameras) < 2 or axis_spread_deg(cameras) <= FORWARD_MAX_ANGLE_DEG else "object"


def _focus_depths(cameras: Cameras, focus: Tensor | None) -> Tensor:
    """Depth [N] of the focus point in each camera; without a usable one, ten times the camera spread."""
    if focus is not None:
        depth = cameras.project(focus[None].to(cameras.dtype))[1][:, 0].to(torch.float64)
        if bool((depth > 0).all()):
            return depth
    centers = cameras.centers.to(torch.float64)
    spread = float((centers - centers.mean(0)).norm(dim=-1).max()) if len(cameras) > 1 else 0.0
    return torch.full((len(cameras),), 10.0 * spread if spread > 0 else 1.0, dtype=torch.float64)


def bounds_from_geometry(cameras: Cameras, layout: Layout) -> tuple[Tensor, Tensor]:
    """Fallback near/far [N] from the cameras alone, as multiples of each camera's depth of the focus point.

    Object layout: 0.5x and 1.5x (NeRF-Synthetic's 2/6 at distance 4); forward layout: 0.25x and 4x.
    """
    depth = _focus_depths(cameras, focus_point(cameras))
    lo, hi = (OBJECT_NEAR_RATIO, OBJECT_FAR_RATIO) if layout == "object" else (FORWARD_NEAR_RATIO, FORWARD_FAR_RATIO)
    return depth * lo, depth * hi


def bounds_from_depths(depths: list[Tensor], fallback: tuple[Tensor, Tensor],
                       percentiles: tuple[float, float] = POINT_PERCENTILES) -> tuple[Tensor, Tensor]:
    """Near/far [N] as the ``percentiles`` (LLFF's POINT_PERCENTILES unless given) of each view's point depths
    [P_i] (positive ones only).

    A view that sees no point keeps its ``fallback`` bounds.
    """
    near, far = fallback[0].clone(), fallback[1].clone()
    q = torch.tensor([p / 100.0 for p in percentiles], dtype=torch.float64)
    for i, d in enumerate(depths):
        d = d.to(torch.float64)
        d = d[d > 0]
        if d.numel() > 0:
            near[i], far[i] = torch.quantile(d, q)
    return near, far


def point_depths(cameras: Cameras, points: Tensor) -> list[Tensor]:
    """Depths of the points [P, 3] in front of each camera that project inside its image: N tensors [P_i].

    One camera at a time, so memory stays O(P) for large point clouds.
    """
    out = []
    for n in range(len(cameras)):
        uv, depth = cameras.subset([n]).project(points.to(cameras.dtype))  # [1, P, 2], [1, P]
        inside = (depth > 0) & (uv[..., 0] >= 0) & (uv[..., 0] <= cameras.width) \
            & (uv[..., 1] >= 0) & (uv[..., 1] <= cameras.height)
        out.append(depth[inside])
    return out


# A step between views next to each other in name order counts as a jump above both of these: a photographer's walk
# moves a few degrees a photo, and its poses folded by a symmetric object jump back ~155 degrees.
JUMP_MIN_DEG, JUMP_MEDIAN_RATIO = 60.0, 8.0
# Two clips of one walk give one jump; a fold gives one per pass.
FOLD_MIN_JUMPS = 2


def walk_jumps(cameras: Cameras, center: Tensor) -> list[tuple[int, float]]:
    """Where an object capture's cameras, taken in their stored (name) order, jump about ``center`` [3].

    Returns:
        [(i, degrees)]: views i and i + 1 sit ``degrees`` apart about the centre, over JUMP_MIN_DEG and
        JUMP_MEDIAN_RATIO times the median step. Photos not taken in name order have a large median step and no jump.
    """
    directions = torch.nn.functional.normalize(cameras.centers.to(torch.float64) - center.to(torch.float64), dim=-1)
    if len(directions) < 3:
        return []
    steps = torch.rad2deg(torch.arccos((directions[1:] * directions[:-1]).sum(-1).clamp(-1.0, 1.0)))  # [N - 1]
    limit = max(JUMP_MIN_DEG, JUMP_MEDIAN_RATIO * float(steps.median()))
    return [(i, float(step)) for i, step in enumerate(steps.tolist()) if step > limit]


def folded_walk_warning(names: Sequence[str], cameras: Cameras, center: Tensor) -> str | None:
    """A one-line warning when an object capture's poses jump back and forth between photos next to each other in
    name order (:func:`walk_jumps`), as folded poses do (docs/commands/poses.md "Folded walks"); else None."""
    jumps = walk_jumps(cameras, center)
    if len(jumps) < FOLD_MIN_JUMPS:
        return None
    shown = ", ".join(f"{names[i]} | {names[i + 1]} ({step:.0f} deg)" for i, step in jumps[:3])
    return (f"warning: the poses put {len(jumps)} pairs of photos next to each other in name order far apart "
            f"about the scene centre ({shown}{' ...' if len(jumps) > 3 else ''}); if they were taken in that "
            "order, a symmetric object probably folded the walk: renders blend two halves of the scene. "
            "`insertnerf poses <images> --out <scene>` estimates the poses again and unfolds such walks.")
