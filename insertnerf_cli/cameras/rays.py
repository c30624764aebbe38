"""Rays and samples along them. Directions are scaled so that their camera-z component is 1, which makes the
ray parameter t equal to the camera depth: near/far bounds and rendered depth maps are then z-depths."""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras, check_shape


@dataclass(frozen=True)
class Rays:
    """R rays with per-ray bounds.

    Attributes:
        origins: [R, 3] world positions.
        directions: [R, 3] world directions with camera-z = 1 (not unit length).
        near, far: [R] bounds of t (camera depth).
    """

    origins: Tensor  # [R, 3]
    directions: Tensor  # [R, 3]
    near: Tensor  # [R]
    far: Tensor  # [R]

    def __post_init__(self) -> None:
        check_shape("origins", self.origins, (None, 3))
        check_shape("directions", self.directions, (self.origins.shape[0], 3))
        check_shape("near", self.near, (self.origins.shape[0],))
        check_shape("far", self.far, (self.origins.shape[0],))

    def __len__(self) -> int:
        return self.origins.shape[0]

    def __getitem__(self, index: slice | Tensor) -> "Rays":
        return Rays(self.origins[index], self.directions[index], self.near[index], self.far[index])

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> "Rays":
        return Rays(*(t.to(device=device, dtype=dtype) for t in (self.origins, self.directions, self.near, self.far)))


def rays_from_pixels(cameras: Cameras, uv: Tensor, near: Tensor, far: Tensor) -> Rays:
    """Rays through pixel positions uv [N, P, 2] of N cameras, with per-camera bounds near/far [N].

    Returns R = N * P rays, camera-major.
    """
    check_shape("uv", uv, (len(cameras), None, 2))
    n, p = uv.shape[:2]
    directions = cameras.ray_directions(uv).reshape(n * p, 3)
    origins = cameras.centers.to(uv)[:, None, :].expand(n, p, 3).reshape(n * p, 3)
    return Rays(origins, directions, near.to(uv).repeat_interleave(p), far.to(uv).repeat_interleave(p))


def rays_for_image(cameras: Cameras, near: Tensor, far: Tensor) -> Rays:
    """Rays through every pixel centre of each camera: R = N * H * W, row-major per image."""
    uv = cameras.pixel_grid().reshape(1, -1, 2).expand(len(cameras), -1, -1)
    return rays_from_pixels(cameras, uv, near, far)
