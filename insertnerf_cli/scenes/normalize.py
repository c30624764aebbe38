"""Scene normalisation: recentre and rescale a scene to canonical units, keeping the similarity to undo it.

The rule (also in docs/formats.md), world orientation kept (no rotation):
- object layout: the centre is the least-squares focus point of the optical axes (the cameras' centroid when
  the axes are parallel), and the scale puts the mean camera distance to it at OBJECT_RADIUS = 4, as in
  NeRF-Synthetic;
- forward layout: the centre is the cameras' centroid, and the scale puts the smallest near bound at
  1 / FORWARD_NEAR_FRACTION (LLFF loaders scale so that 0.75 * min(near) = 1).
near/far and ``depth_scale`` (so depth files read in the new units) are multiplied by the same scale.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras, check_shape
from insertnerf_cli.errors import SceneError
from insertnerf_cli.scenes.base import Scene
from insertnerf_cli.scenes.geometry import focus_point, folded_walk_warning

OBJECT_RADIUS = 4.0
FORWARD_NEAR_FRACTION = 0.75


@dataclass(frozen=True)
class Similarity:
    """The world similarity x' = scale * rotation @ x + translation.

    Attributes:
        rotation: [3, 3] proper rotation; translation: [3]; scale: positive float.
    """

    rotation: Tensor  # [3, 3]
    translation: Tensor  # [3]
    scale: float

    def __post_init__(self) -> None:
        check_shape("rotation", self.rotation, (3, 3))
        check_shape("translation", self.translation, (3,))
        if not self.scale > 0:
            raise ValueError(f"similarity scale must be positive, got {self.scale}")

    def apply_points(self, points: Tensor) -> Tensor:
        """Points [..., 3] -> [..., 3] in the new world."""
        R, t = self.rotation.to(points), self.translation.to(points)
        return self.scale * points @ R.T + t

    def apply_cameras(self, cameras: Cameras) -> Cameras:
        """The same cameras expressed in the new world (intrinsics and image size unchanged)."""
        return cameras.transform(self.rotation, self.translation, self.scale)

    def inverse(self) -> "Similarity":
        """x = R^T (x' - t) / s, i.e. scale 1/s, rotation R^T, translation -R^T t / s."""
        R_inv = self.rotation.T
        return Similarity(R_inv, -(R_inv @ self.translation) / self.scale, 1.0 / self.scale)

    def to_json(self) -> dict[str, Any]:
        return {"rotation": self.rotation.tolist(), "translation": self.translation.tolist(), "scale": self.scale}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "Similarity":
        try:
            return cls(torch.tensor(data["rotation"], dtype=torch.float64),
                       torch.tensor(data["translation"], dtype=torch.float64), float(data["scale"]))
        except (KeyError, TypeError, ValueError) as err:
            raise SceneError(f"not a similarity (rotation 3x3, translation 3, scale > 0): {err}") from None


def scene_center(scene: Scene) -> Tensor:
    """The point normalisation puts at the origin [3] (see the module docstring)."""
    centers = scene.cameras.centers.to(torch.float64)
    focus = focus_point(scene.cameras) if scene.layout == "object" else None
    return focus if focus is not None else centers.mean(0)


def walk_warning(scene: Scene) -> str | None:
    """geometry.folded_walk_warning for an object capture (forward-facing grids are not walks); else None."""
    if scene.layout != "object":
        return None
    return folded_walk_warning(scene.names, scene.cameras, scene_center(scene))


def normalize_scene(scene: Scene) -> tuple[Scene, Similarity]:
    """The scene in canonical units, and the similarity that maps the user's world to them.

    Returns:
        (normalised scene, similarity); ``similarity.inverse()`` maps rendered geometry back to user units.
    """
    center = scene_center(scene)
    centers = scene.cameras.centers.to(torch.float64)
    if scene.layout == "object":
        radius = float((centers - center).norm(dim=-1).mean())
        scale = OBJECT_RADIUS / radius if radius > 0 else 1.0
    else:
        scale = 1.0 / (FORWARD_NEAR_FRACTION * float(scene.near.min()))
    sim = Similarity(torch.eye(3, dtype=torch.float64), -scale * center, scale)
    normed = scene.with_cameras(sim.apply_cameras(scene.cameras), scene.near * scale, scene.far * scale)
    points = None if scene.points is None else scene.points.transformed(sim)
    return replace(normed, depth_scale=scene.depth_scale * scale, points=points), sim  # depth files in new units
