"""Tiny analytic scenes and configs for the generator's tests: cameras on a circle around a textured sphere."""
from __future__ import annotations

import math

import numpy as np
import torch

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.config import ModelConfig
from insertnerf_cli.model import EncodedViews, InsertNeRF, SourceViews
from insertnerf_cli.rendering.camera_paths import look_at

RADIUS = 3.0  # camera distance from the origin
SPHERE = 1.0  # sphere radius
NEAR, FAR = RADIUS - 1.5 * SPHERE, RADIUS + 1.5 * SPHERE

TINY = ModelConfig(encoder_widths=(8, 8, 8, 8), feature_dims=(4, 4, 4), backbone_decoder_width=4, aggregate_hidden=4,
                   nerf_width=16, nerf_layers=3, appearance_width=16, z_branches=2, film_hidden=8, filter_nodes=4,
                   samples_coarse=16, samples_fine=16, pe_freqs_pos=3, pe_freqs_dir=2, num_views=4)


def orbit_cameras(n: int, size: int, phase: float = 0.0, height: float = 1.0) -> Cameras:
    """n OpenCV cameras on a circle of radius RADIUS at z = ``height``, looking at the origin (float32)."""
    angles = phase + 2 * math.pi * torch.arange(n, dtype=torch.float64) / n
    eyes = torch.stack([RADIUS * torch.cos(angles), RADIUS * torch.sin(angles),
                        torch.full_like(angles, height)], dim=-1)
    c2w = look_at(eyes, torch.zeros(3, dtype=torch.float64), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    K = intrinsics(size, size, size / 2, size / 2).expand(n, 3, 3).clone()
    return Cameras(K, c2w, size, size).to(dtype=torch.float32)


def sphere_images(cameras: Cameras, background: float = 1.0) -> torch.Tensor:
    """Exact ray casts [N, H, W, 3] of a sphere (radius SPHERE at the origin) whose colour is a smooth texture of
    the surface normal, on a uniform background."""
    uv = cameras.pixel_grid().reshape(1, -1, 2).expand(len(cameras), -1, -1)
    d = torch.nn.functional.normalize(cameras.to(dtype=torch.float64).ray_directions(uv.double()), dim=-1).numpy()
    o = cameras.centers.double().numpy()[:, None, :]  # [N, 1, 3]
    b = (d * o).sum(-1)
    disc = b ** 2 - ((o * o).sum(-1) - SPHERE ** 2)
    t = -b - np.sqrt(np.clip(disc, 0.0, None))
    n = (o + t[..., None] * d) / SPHERE  # unit normals where hit
    texture = 0.5 + 0.4 * np.stack([np.sin(3 * n[..., 0] + 1), np.cos(4 * n[..., 1]), np.sin(5 * n[..., 2])], -1)
    rgb = np.where((disc > 0)[..., None], texture, background)
    return torch.from_numpy(rgb.reshape(len(cameras), cameras.height, cameras.width, 3)).float()


def sphere_hit(origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """[R] ray parameter t of each ray's first hit on the sphere (``origins`` + t ``directions``, [R, 3] each; in
    float64), NaN where a ray misses it."""
    d, o = directions.double(), origins.double()
    a, b = (d * d).sum(-1), (d * o).sum(-1)
    disc = b ** 2 - a * ((o * o).sum(-1) - SPHERE ** 2)
    return torch.where(disc > 0, (-b - disc.clamp(min=0.0).sqrt()) / a, torch.nan)


def sphere_views(n: int, size: int, phase: float = 0.0) -> SourceViews:
    cams = orbit_cameras(n, size, phase)
    return SourceViews(sphere_images(cams), cams)


def tiny_model_and_views(size: int = 8, config: ModelConfig = TINY) -> tuple[InsertNeRF, EncodedViews, Cameras]:
    """A TINY-style generator seeded with 0 (eval mode), its encoding of 3 sphere views of 16 px, and a target
    camera of ``size`` px between them."""
    torch.manual_seed(0)
    model = InsertNeRF(config).eval()
    with torch.no_grad():
        encoded = model.encode(sphere_views(3, 16))
    return model, encoded, orbit_cameras(1, size, phase=0.4)


def flat_views(colours: list[tuple[float, float, float]], size: int = 16) -> SourceViews:
    """Views on a circle (view 0 at phase 0), image i one uniform colour colours[i]: what every view sees of any
    point, at infinity too, is its colour."""
    cams = orbit_cameras(len(colours), size)
    images = torch.tensor(colours, dtype=torch.float32)[:, None, None, :].expand(-1, size, size, -1).contiguous()
    return SourceViews(images, cams)
