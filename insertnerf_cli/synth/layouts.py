"""Camera rigs for the four layouts, as :class:`~insertnerf_cli.cameras.camera.Cameras` (OpenCV c2w, world z up).

* object: cameras on a sphere or upper hemisphere around the subject, looking at it (NeRF-Synthetic).
* 360: a hand-held orbit around the subject at a wobbling height and distance, inside the enclosure.
* forward: cameras on a small plane facing +y, parallel or converging (LLFF).
* handheld: a hand-held forward-facing grid with a small baseline (LLFF's own captures), or a phone walking
  around the subject at varying height and distance (a full loop or part of one).

Every rig shares one pinhole K with fx = fy and the principal point at the image centre; the focal length
and the aspect ratio are drawn per scene.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.synth.world import Stage

# Field of view of the image's long side, degrees: from a short tele (NeRF-Synthetic is 39.6) to a phone's wide.
FOV_RANGE = (35.0, 75.0)
_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Frame:
    """Image size and focal length of a rig (pixels)."""

    height: int
    width: int
    focal: float

    @property
    def short_half_fov(self) -> float:
        """Half the field of view (radians) of the image's short side."""
        return float(np.arctan(0.5 * min(self.height, self.width) / self.focal))


def random_frame(rng: np.random.Generator, long_side: int, aspects: tuple[float, ...],
                 fov_range: tuple[float, float] = FOV_RANGE) -> Frame:
    """Draw an aspect ratio (landscape 70%, portrait 30%) and a focal length for a ``long_side`` image, its long
    side's field of view uniform in ``fov_range`` (degrees). The draws do not depend on the range, so one seed
    gives the same scene at another range."""
    aspect = float(aspects[rng.integers(len(aspects))])
    short = max(1, int(round(long_side / aspect)))
    height, width = (short, long_side) if rng.random() < 0.7 else (long_side, short)
    fov = np.radians(rng.uniform(*fov_range))
    return Frame(height, width, float(0.5 * long_side / np.tan(fov / 2)))


def look_at(eyes: np.ndarray, targets: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """OpenCV camera-to-world [N, 4, 4] at ``eyes`` [N, 3] looking at ``targets`` [N, 3], z up, then rolled.

    With world z up, x = forward x up points right and y = forward x right points down (OpenCV).
    """
    forward = targets - eyes
    forward /= np.linalg.norm(forward, axis=1, keepdims=True)
    # Looking straight up or down leaves "right" undefined: fall back to the world y axis as up.
    up = np.where(np.abs(forward @ _UP)[:, None] > 0.999, np.array([0.0, 1.0, 0.0]), _UP)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    down = np.cross(forward, right)
    c, s = np.cos(roll)[:, None], np.sin(roll)[:, None]
    right, down = c * right + s * down, c * down - s * right
    c2w = np.tile(np.eye(4), (len(eyes), 1, 1))
    c2w[:, :3, 0], c2w[:, :3, 1], c2w[:, :3, 2], c2w[:, :3, 3] = right, down, forward, eyes
    return c2w


def _cameras(frame: Frame, c2w: np.ndarray) -> Cameras:
    K = intrinsics(frame.focal, frame.focal, frame.width / 2, frame.height / 2)
    return Cameras(K.expand(len(c2w), 3, 3).clone(), torch.from_numpy(c2w), frame.height, frame.width)


def _below_ceiling(stage: Stage, eyes: np.ndarray) -> np.ndarray:
    """Camera centres [N, 3] lowered where needed to stay a little under the stage's ceiling."""
    eyes = eyes.copy()
    eyes[:, 2] = np.minimum(eyes[:, 2], stage.ceiling - 0.2 * stage.radius)
    return eyes


def _fit_distance(rng: np.random.Generator, frame: Frame, radius: float) -> float:
    """Distance at which a sphere of ``radius`` fills 60-95% of the short side's half field of view."""
    return float(radius / np.sin(rng.uniform(0.6, 0.95) * frame.short_half_fov))


def object_rig(rng: np.random.Generator, stage: Stage, frame: Frame, views: int) -> Cameras:
    """Cameras on a sphere (or the upper hemisphere when there is a ground) looking at the subject."""
    distance = min(_fit_distance(rng, frame, stage.radius), stage.limit)
    lowest = -1.0 if stage.ground is None and rng.random() < 0.5 else np.sin(np.radians(rng.uniform(0, 15)))
    z = rng.uniform(lowest, 0.98, views)  # uniform in z = uniform on the sphere's area
    azimuth = rng.uniform(0, 2 * np.pi, views)
    radial = np.sqrt(1 - z ** 2)
    directions = np.stack([radial * np.cos(azimuth), radial * np.sin(azimuth), z], axis=1)
    jitter = rng.uniform(0.9, 1.0, views)[:, None] if rng.random() < 0.5 else 1.0
    eyes = _below_ceiling(stage, stage.center + distance * jitter * directions)
    targets = stage.center + rng.normal(0, 0.05 * stage.radius, (views, 3))
    return _cameras(frame, look_at(eyes, targets, np.zeros(views)))


def orbit_rig(rng: np.random.Generator, stage: Stage, frame: Frame, views: int) -> Cameras:
    """A hand-held orbit: one or two loops around the subject with wobbling radius, height and aim."""
    distance = min(_fit_distance(rng, frame, stage.radius), stage.limit)
    loops = 1 if rng.random() < 0.7 else 2
    azimuth = rng.uniform(0, 2 * np.pi) + np.linspace(0, 2 * np.pi * loops, views, endpoint=False)
    azimuth += rng.normal(0, 0.3 * np.pi / views, views)
    base_elevation = np.radians(rng.uniform(5, 40))
    loop_offset = np.where(np.arange(views) * loops // views == 1, np.radians(rng.uniform(10, 25)), 0.0)
    elevation = base_elevation + loop_offset + np.radians(rng.normal(0, 3, views))
    radius = distance * (1 - 0.04 * (1 + np.sin(azimuth * rng.integers(1, 4) + rng.uniform(0, 6))))
    eyes = stage.center + radius[:, None] * np.stack(
        [np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation), np.sin(elevation)], axis=1)
    if stage.ground is not None:  # a person holds the phone above the floor
        eyes[:, 2] = np.maximum(eyes[:, 2], stage.ground + 0.3 * stage.radius)
    eyes = _below_ceiling(stage, eyes)
    targets = stage.center + rng.normal(0, 0.1 * stage.radius, (views, 3))
    return _cameras(frame, look_at(eyes, targets, np.radians(rng.normal(0, 2, views))))


def forward_rig(rng: np.random.Generator, stage: Stage, frame: Frame, views: int) -> Cameras:
    """Cameras on a small x-z rectangle around ``stage.center`` facing +y (parallel or converging)."""
    width = stage.depth * rng.uniform(0.15, 0.45)
    height = width * rng.uniform(0.3, 0.8)
    if rng.random() < 0.5:  # a jittered grid, as when stepping a tripod
        cols = int(np.ceil(np.sqrt(views * width / height)))
        cell = np.arange(views)
        grid = np.stack([(cell % cols + 0.5) / cols, (cell // cols + 0.5) / np.ceil(views / cols)], axis=1)
        offsets = grid - 0.5 + rng.normal(0, 0.05, (views, 2))
    else:
        offsets = rng.uniform(-0.5, 0.5, (views, 2))
    eyes = stage.center + np.stack([offsets[:, 0] * width, np.zeros(views), offsets[:, 1] * height], axis=1)
    yaw, pitch = np.radians(rng.uniform(-10, 10)), np.radians(rng.uniform(-12, 3))
    heading = np.array([np.sin(yaw) * np.cos(pitch), np.cos(yaw) * np.cos(pitch), np.sin(pitch)])
    if rng.random() < 0.5:  # converge on a point in the middle of the scene
        focus = stage.center + heading * rng.uniform(1.5, 4.0) * stage.depth
        targets = focus + rng.normal(0, 0.02 * stage.depth, (views, 3))
    else:  # parallel optical axes with hand-held jitter
        targets = eyes + heading + rng.normal(0, np.radians(1.5), (views, 3))
    return _cameras(frame, look_at(eyes, targets, np.radians(rng.normal(0, 1.5, views))))


def handheld_grid_rig(rng: np.random.Generator, stage: Stage, frame: Frame, views: int) -> Cameras:
    """A person stepping a phone over a rough plane at ``stage.center`` facing the subject at (0, depth, 0):
    serpentine rows of a jittered grid or a loose scatter, 10-30% of the subject distance wide (a few % of
    the scene's depth), the plane rough by 10% of its width along the view, optical axes roughly parallel
    or converging on the subject, with 0.5-2.5 degrees of hand-held rotation per view."""
    width = stage.depth * rng.uniform(0.1, 0.3)
    height = width * rng.uniform(0.4, 0.9)
    if rng.random() < 0.6:
        cols = max(1, int(round(np.sqrt(views * width / height))))
        rows = int(np.ceil(views / cols))
        row, col = np.arange(views) // cols, np.arange(views) % cols
        col = np.where(row % 2 == 1, cols - 1 - col, col)  # serpentine: the way a person sweeps
        offsets = np.stack([(col + 0.5) / cols, (row + 0.5) / rows], axis=1) - 0.5
        offsets += rng.normal(0, 0.15, (views, 2)) / np.array([cols, rows])
    else:
        offsets = rng.uniform(-0.5, 0.5, (views, 2))
    eyes = stage.center + np.stack([offsets[:, 0] * width, rng.normal(0, 0.1 * width, views),
                                    offsets[:, 1] * height], axis=1)
    subject = np.array([0.0, stage.depth, 0.0])
    aim = subject + rng.normal(0, np.tan(np.radians(3.0)) * stage.depth, 3)  # the photographer's framing
    shake = np.radians(rng.uniform(0.5, 2.5))
    if rng.random() < 0.5:  # every shot re-aimed at the subject
        targets = aim + rng.normal(0, shake * stage.depth, (views, 3))
    else:  # one heading kept while stepping sideways
        heading = (aim - stage.center) / np.linalg.norm(aim - stage.center)
        targets = eyes + heading + rng.normal(0, shake, (views, 3))
    return _cameras(frame, look_at(eyes, targets, rng.normal(0, shake, views)))


def phone_orbit_rig(rng: np.random.Generator, stage: Stage, frame: Frame, views: int) -> Cameras:
    """A phone carried around the subject: a full loop (60%) or a 110-290 degree arc, the distance varying
    smoothly by up to +-25% and the height between 5 and ~55 degrees of elevation along the walk."""
    base = min(_fit_distance(rng, frame, stage.radius), 0.85 * stage.limit)
    arc = 2 * np.pi if rng.random() < 0.6 else np.radians(rng.uniform(110, 290))
    t = np.arange(views) / views if arc == 2 * np.pi else np.linspace(0, 1, views)
    azimuth = rng.uniform(0, 2 * np.pi) + arc * t + rng.normal(0, 0.2 * arc / views, views)
    waves = rng.integers(1, 4, 2)
    phases = rng.uniform(0, 2 * np.pi, 2)
    swing = rng.uniform(0.08, 0.25) * np.sin(2 * np.pi * waves[0] * t + phases[0])
    distance = np.clip(base * np.exp(swing), 1.8 * stage.radius, stage.limit)
    elevation = np.radians(rng.uniform(5, 35) + rng.uniform(3, 10) * (1 + np.sin(2 * np.pi * waves[1] * t + phases[1]))
                           + rng.normal(0, 2, views))
    eyes = stage.center + distance[:, None] * np.stack(
        [np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation), np.sin(elevation)], axis=1)
    if stage.ground is not None:
        eyes[:, 2] = np.maximum(eyes[:, 2], stage.ground + 0.3 * stage.radius)
    eyes = _below_ceiling(stage, eyes)
    targets = stage.center + rng.normal(0, 0.15 * stage.radius, (views, 3))
    return _cameras(frame, look_at(eyes, targets, np.radians(rng.normal(0, 3, views))))


def handheld_rig(rng: np.random.Generator, stage: Stage, frame: Frame, views: int) -> Cameras:
    """The hand-held capture the world was composed for (``stage.style``)."""
    return (handheld_grid_rig if stage.style == "grid" else phone_orbit_rig)(rng, stage, frame, views)


RIGS = {"object": object_rig, "360": orbit_rig, "forward": forward_rig, "handheld": handheld_rig}


def held_out_indices(views: int, test_views: int) -> list[int]:
    """``test_views`` indices spread evenly over ``views`` (held-out views interleave with the training ones)."""
    test_views = min(max(test_views, 0), views)
    return [int((i + 0.5) * views / test_views) for i in range(test_views)]
