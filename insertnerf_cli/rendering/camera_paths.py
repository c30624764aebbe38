"""Camera paths to render: an orbit (turntable) around object-centric and 360-degree captures, an LLFF-style spiral
in front of forward-facing ones, or the input poses themselves.

Every path is built from the input cameras of a (normalised) scene and keeps the OpenCV c2w convention of
cameras.py. Orbit and spiral frames all look at one focus point; both loops are closed: the step from the last
frame back to the first equals every other step, so a video of the path loops without a jump.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras, check_shape
from insertnerf_cli.errors import UserError
from insertnerf_cli.scenes.geometry import focus_point as least_squares_focus
from insertnerf_cli.scenes.views import ViewMethod, nearest_views

PathKind = Literal["orbit", "spiral", "input"]
PATH_KINDS: tuple[str, ...] = ("orbit", "spiral", "input")

# LLFF's render path: two turns with a slow in-and-out motion (zrate 0.5 closes after exactly two turns),
# radii from the 90th percentile of camera offsets. Its focus is not LLFF's (a disparity mix of near and far, about
# 4 x near) but the depth within [NEAR_MARGIN x near, FAR_FACTOR x far] at which the frames turn least from the
# inputs beside them: a generalizable renderer draws only what its references saw, and a focus that turns the
# frames away from the photos beside them draws part of each frame from surfaces no reference sees well
# (bench/path_turn.py measures the turn; docs/research-log.md, Camera paths).
SPIRAL_TURNS = 2
SPIRAL_ZRATE = 0.5
SPIRAL_RADIUS_QUANTILE = 0.9
SPIRAL_NEAR_MARGIN = 0.9
SPIRAL_FAR_FACTOR = 5.0
# A spiral needs a common viewing direction: the mean of the unit optical axes must keep at least this length
# (about 45 degrees of spread), else the inputs surround the scene and an orbit is the path to take.
SPIRAL_MIN_AXIS_AGREEMENT = 0.7
# The spiral's focus depth is chosen among this many depths between its bounds, scoring the turn of this many
# frames along the path (whatever --frames asks: the same focus for every frame count).
SPIRAL_FOCUS_DEPTHS = 256
SPIRAL_FOCUS_SAMPLES = 64


@dataclass(frozen=True)
class CameraPath:
    """F frames to render.

    Attributes:
        kind: "orbit", "spiral" or "input".
        cameras: F cameras (OpenCV c2w) at the output image size.
        near, far: [F] depth bounds per frame, in the units of the cameras.
        focus: [3] the point the frames look at (for "input": the least-squares focus of the input axes).
        source_index: for "input" the input view each frame re-renders, else None.
    """

    kind: str
    cameras: Cameras
    near: Tensor  # [F]
    far: Tensor  # [F]
    focus: Tensor  # [3]
    source_index: list[int] | None = None

    def __len__(self) -> int:
        return len(self.cameras)


def focus_point(cameras: Cameras) -> Tensor:
    """The point [3] closest (least squares) to every optical axis, as instant-ngp's colmap2nerf does.

    When the axes are (nearly) parallel the least-squares system is singular; the fallback is one unit in front
    of the mean camera centre, along the mean axis.
    """
    focus = least_squares_focus(cameras)
    if focus is None:
        return cameras.centers.mean(0) + torch.nn.functional.normalize(cameras.forward, dim=-1).mean(0)
    return focus.to(cameras.c2w)


def mean_up(cameras: Cameras) -> Tensor:
    """Unit world "up" [3]: minus the mean camera y axis (OpenCV y points down in the image)."""
    up = -cameras.c2w[:, :3, 1].mean(0)
    if up.norm() < 1e-6:
        raise UserError("the input cameras have no common up direction; use --path input to re-render them")
    return up / up.norm()


def look_at(eyes: Tensor, target: Tensor, up: Tensor) -> Tensor:
    """OpenCV c2w [F, 4, 4] for cameras at ``eyes`` [F, 3] looking at ``target`` [3] with world ``up`` [3].

    OpenCV axes: z forward (to the target), y down (against up), x = y cross z (right).
    """
    check_shape("eyes", eyes, (None, 3))
    z = torch.nn.functional.normalize(target - eyes, dim=-1)  # [F, 3]
    x = torch.linalg.cross(-up.expand_as(z), z)
    if (x.norm(dim=-1) < 1e-6).any():
        raise UserError("a path camera looks straight up or down; the up direction is undefined there")
    x = torch.nn.functional.normalize(x, dim=-1)
    y = torch.linalg.cross(z, x)
    c2w = torch.zeros(eyes.shape[0], 4, 4, dtype=eyes.dtype, device=eyes.device)
    c2w[:, :3, 0], c2w[:, :3, 1], c2w[:, :3, 2], c2w[:, :3, 3] = x, y, z, eyes
    c2w[:, 3, 3] = 1.0
    return c2w


def _basis(up: Tensor, reference: Tensor) -> tuple[Tensor, Tensor]:
    """Two unit vectors spanning the plane normal to ``up``; the first points along ``reference``'s projection."""
    e1 = reference - (reference @ up) * up
    if e1.norm() < 1e-6:  # reference parallel to up: any horizontal direction will do
        e1 = torch.linalg.cross(up, torch.eye(3, dtype=up.dtype, device=up.device)[int(up.abs().argmin())])
    e1 = e1 / e1.norm()
    return e1, torch.linalg.cross(up, e1)


def _path_intrinsics(cameras: Cameras, height: int, width: int, frames: int) -> Tensor:
    """K [F, 3, 3] for new frames: the inputs' median focal lengths (rescaled), principal point centred."""
    K = cameras.rescale(height, width).K
    fx, fy = K[:, 0, 0].median(), K[:, 1, 1].median()
    out = torch.zeros(frames, 3, 3, dtype=K.dtype, device=K.device)
    out[:, 0, 0], out[:, 1, 1], out[:, 0, 2], out[:, 1, 2], out[:, 2, 2] = fx, fy, width / 2, height / 2, 1.0
    return out


def orbit_path(cameras: Cameras, near: Tensor, far: Tensor, frames: int, size: tuple[int, int]) -> CameraPath:
    """A turntable: ``frames`` cameras evenly spaced on a horizontal circle around the focus point.

    The cameras keep the inputs' mean distance to the focus and their mean elevation angle (so a capture from
    all over a sphere gives a circle as far out as its cameras, not one shrunk towards the middle), start at the
    first input camera's azimuth, and stop one step short of 360 degrees so the loop closes. near/far are the
    inputs' overall bounds (render narrows them per frame with :func:`with_reference_bounds`).
    """
    _check_frames(frames)
    focus, up = focus_point(cameras), mean_up(cameras)
    offsets = cameras.centers - focus  # [N, 3]
    distance = offsets.norm(dim=-1)  # [N]
    radius = distance.mean()
    elevation = torch.asin(((offsets @ up) / distance.clamp(min=1e-12)).clamp(-1.0, 1.0)).mean()
    e1, e2 = _basis(up, offsets[0])
    angles = torch.arange(frames, dtype=offsets.dtype, device=offsets.device) * (2 * math.pi / frames)  # [F]
    ring = torch.cos(angles)[:, None] * e1 + torch.sin(angles)[:, None] * e2  # [F, 3] unit, horizontal
    eyes = focus + radius * (torch.cos(elevation) * ring + torch.sin(elevation) * up)
    c2w = look_at(eyes, focus, up)
    h, w = size
    path_cams = Cameras(_path_intrinsics(cameras, h, w, frames), c2w, h, w)
    return CameraPath("orbit", path_cams, near.min().expand(frames).clone(), far.max().expand(frames).clone(), focus)


def spiral_path(cameras: Cameras, near: Tensor, far: Tensor, frames: int, size: tuple[int, int]) -> CameraPath:
    """LLFF's spiral: ``frames`` cameras circling around the average pose, all looking at one focus point.

    The radii along the average camera's x, y, z are the 90th percentiles of the input centres' offsets; two turns
    with a z motion at half rate close the loop. The focus lies along the average optical axis at the depth that
    keeps the frames looking where the inputs looked (turn_matched_depth), not at LLFF's.
    """
    _check_frames(frames)
    agreement = float(torch.nn.functional.normalize(cameras.forward, dim=-1).mean(0).norm())
    if agreement < SPIRAL_MIN_AXIS_AGREEMENT:
        raise UserError("the input cameras look in too many directions for a spiral path (they surround the "
                        "scene); use --path orbit or --path input")
    centre = cameras.centers.mean(0)
    axes = [torch.nn.functional.normalize(cameras.c2w[:, :3, i].mean(0), dim=0) for i in range(3)]
    offsets = cameras.centers - centre  # [N, 3]
    radii = [torch.quantile((offsets @ a).abs(), SPIRAL_RADIUS_QUANTILE) for a in axes]

    def spiral(count: int) -> Tensor:  # [count, 3] eyes evenly spaced along the two turns
        t = torch.arange(count, dtype=offsets.dtype, device=offsets.device) * (2 * math.pi * SPIRAL_TURNS / count)
        waves = [torch.cos(t), torch.sin(t), torch.sin(SPIRAL_ZRATE * t)]
        return centre + sum(r * wave[:, None] * a for r, wave, a in zip(radii, waves, axes))

    bounds = (SPIRAL_NEAR_MARGIN * float(near.min()), SPIRAL_FAR_FACTOR * float(far.max()))
    depth = turn_matched_depth(cameras, spiral(SPIRAL_FOCUS_SAMPLES), centre, axes[2], bounds)
    focus = centre + depth * axes[2]
    c2w = look_at(spiral(frames), focus, -axes[1])
    h, w = size
    path_cams = Cameras(_path_intrinsics(cameras, h, w, frames), c2w, h, w)
    return CameraPath("spiral", path_cams, near.min().expand(frames).clone(), far.max().expand(frames).clone(), focus)


def turn_matched_depth(cameras: Cameras, eyes: Tensor, centre: Tensor, forward: Tensor,
                       bounds: tuple[float, float]) -> float:
    """The depth s within ``bounds`` (near, far) at which cameras at ``eyes`` [F, 3] looking at centre + s
    ``forward`` (both [3]) turn least from the input cameras beside them: the smallest mean angle between an eye's
    axis and its nearest input camera's (by position, as forward-facing frames pick their references), among
    SPIRAL_FOCUS_DEPTHS depths evenly spaced in log depth (the farthest of equals). Parallel inputs give the far
    bound, inputs turned toward one point give its depth."""
    inputs = torch.nn.functional.normalize(cameras.forward.to(torch.float64), dim=-1)  # [N, 3]
    eyes = eyes.to(inputs)
    beside = inputs[torch.cdist(eyes, cameras.centers.to(inputs)).argmin(dim=1)]  # [F, 3]
    depths = torch.logspace(math.log10(bounds[0]), math.log10(bounds[1]), SPIRAL_FOCUS_DEPTHS,
                            dtype=torch.float64, device=inputs.device)  # [D]
    targets = centre.to(inputs) + depths[:, None] * forward.to(inputs)  # [D, 3]
    views = torch.nn.functional.normalize(targets[:, None] - eyes[None], dim=-1)  # [D, F, 3]
    turn = torch.acos((views * beside[None]).sum(dim=-1).clamp(-1.0, 1.0)).mean(dim=-1)  # [D]
    farthest_best = SPIRAL_FOCUS_DEPTHS - 1 - int(turn.flip(0).argmin())
    return float(depths[farthest_best])


def input_path(cameras: Cameras, near: Tensor, far: Tensor, size: tuple[int, int],
               frames: int | None = None) -> CameraPath:
    """The input cameras themselves (rescaled to ``size``), or ``frames`` of them evenly spread, with their bounds."""
    index = list(range(len(cameras)))
    if frames is not None and frames < len(index):
        _check_frames(frames)
        index = sorted({round(i * (len(cameras) - 1) / max(frames - 1, 1)) for i in range(frames)})
    h, w = size
    return CameraPath("input", cameras.subset(index).rescale(h, w), near[index].clone(), far[index].clone(),
                      focus_point(cameras), source_index=index)


def given_path(cameras: Cameras, near: Tensor, far: Tensor, given: Cameras, resolution: int | None) -> CameraPath:
    """The ``given`` cameras (a path file's, already in the normalised world) at their own size, or scaled down so
    that the long side is ``resolution`` (never up); each frame's bounds start as the inputs' widest
    (with_reference_bounds then narrows them to its references')."""
    h, w = given.height, given.width
    if resolution and resolution < max(h, w):
        h, w = max(1, round(h * resolution / max(h, w))), max(1, round(w * resolution / max(h, w)))
    frames = len(given)
    return CameraPath("file", given.rescale(h, w), near.min().expand(frames).clone(), far.max().expand(frames).clone(),
                      focus_point(given))


def make_path(kind: str, cameras: Cameras, near: Tensor, far: Tensor, frames: int,
              size: tuple[int, int]) -> CameraPath:
    """Dispatch on ``kind`` ("orbit", "spiral" or "input"); see the functions above."""
    if kind == "orbit":
        return orbit_path(cameras, near, far, frames, size)
    if kind == "spiral":
        return spiral_path(cameras, near, far, frames, size)
    if kind == "input":
        return input_path(cameras, near, far, size, frames)
    raise UserError(f"unknown camera path {kind!r}; choose one of {', '.join(PATH_KINDS)}")


def with_reference_bounds(path: CameraPath, cameras: Cameras, near: Tensor, far: Tensor, views: int,
                          method: ViewMethod) -> CameraPath:
    """``path`` with each frame's near and far the medians of the bounds [N] of the ``views`` input cameras it is
    rendered from (the nearest by ``method``, as view_renderer picks them); input-path frames keep their own.

    One pair for a whole orbit or spiral (the inputs' smallest near, largest far) spreads a frame's samples over
    depths its reference views do not see; the references' medians come close to each view's own bounds
    (docs/research-log.md, Camera paths).
    """
    if path.source_index is not None:
        return path
    refs = torch.tensor([nearest_views(c2w, cameras.c2w, views, method) for c2w in path.cameras.c2w])  # [F, k]
    return replace(path, near=near[refs].median(dim=-1).values, far=far[refs].median(dim=-1).values)


def default_path_kind(layout: str) -> str:
    """An orbit for object-centric / 360-degree captures, a spiral for forward-facing ones."""
    return "spiral" if layout == "forward" else "orbit"


def _check_frames(frames: int) -> None:
    if frames < 1:
        raise UserError(f"--frames must be at least 1, got {frames}")
