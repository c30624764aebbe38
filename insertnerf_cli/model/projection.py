"""Projection of ray samples into every reference view: bilinear features and colours, validity, direction cues.

Layout: per-view tensors are [V, R, S, C] so that reductions over views run along the first axis; one
``grid_sample`` call per feature scale (and one for the colours) gathers every sample in every view at once.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from ..cameras import Cameras
from .types import EncodedViews


@dataclass(frozen=True)
class Projected:
    """What each reference view sees of each sample.

    Attributes:
        features: per scale (coarse to fine) [V, R, S, C_l] bilinear U-Net features.
        colours: [V, R, S, 3] bilinear reference colours.
        mask: [V, R, S, 1] 1 where the sample is in front of the view and inside its image, else 0.
        ray_diff: [V, R, S, 4] (unit ref direction - unit query direction, their dot product): how differently
            the view looks at the sample.
    """

    features: tuple[Tensor, ...]
    colours: Tensor  # [V, R, S, 3]
    mask: Tensor  # [V, R, S, 1]
    ray_diff: Tensor  # [V, R, S, 4]

    @property
    def cos(self) -> Tensor:
        """[V, R, S, 1] cosine between the query ray and the view's ray through the sample."""
        return self.ray_diff[..., 3:]


def projection_matrices(cameras: Cameras) -> Tensor:
    """K [R | t] [V, 3, 4] of each camera: homogeneous world point -> (u z, v z, z)."""
    w2c = cameras.w2c
    return cameras.K @ w2c[:, :3, :]


def project_samples(encoded: EncodedViews, points: Tensor, directions: Tensor) -> Projected:
    """Sample every reference view at every point.

    Args:
        encoded: the encoded reference views (V).
        points: [R, S, 3] world positions of the samples.
        directions: [R, 3] query ray directions (any length).
    """
    rays, samples = points.shape[:2]
    flat = points.reshape(1, rays * samples, 3)  # [1, P, 3]
    proj = encoded.projection.to(points)  # [V, 3, 4]
    pix = flat @ proj[:, :, :3].transpose(1, 2) + proj[:, None, :, 3]  # [V, P, 3]
    depth = pix[..., 2]  # [V, P]
    uv = pix[..., :2] / depth.clamp(min=1e-6)[..., None]  # [V, P, 2]
    inside = ((depth > 1e-6) & (uv[..., 0] >= 0) & (uv[..., 0] <= encoded.width)
              & (uv[..., 1] >= 0) & (uv[..., 1] <= encoded.height))  # [V, P]
    pad_h, pad_w = encoded.padded_size
    # align_corners=False: -1 and +1 are the outer edges of the padded image, matching pixel (0, 0) = [0, 1]^2.
    scale = torch.tensor([2.0 / pad_w, 2.0 / pad_h], dtype=uv.dtype, device=uv.device)
    grid = (uv * scale - 1.0).clamp(-2.0, 2.0)[:, None]  # [V, 1, P, 2]; clamp keeps far-off points finite
    views = len(encoded)
    features = tuple(_sample(f, grid).reshape(views, rays, samples, -1) for f in encoded.features)
    colours = _sample(encoded.images, grid).reshape(views, rays, samples, 3)
    mask = inside.to(points.dtype).reshape(views, rays, samples, 1)
    return Projected(features, colours, mask, _ray_diff(encoded.centers.to(points), points, directions))


def _sample(maps: Tensor, grid: Tensor) -> Tensor:
    """Bilinear lookup of maps [V, C, h, w] at grid [V, 1, P, 2] -> [V, P, C] (zeros outside)."""
    out = F.grid_sample(maps, grid, mode="bilinear", padding_mode="zeros", align_corners=False)  # [V, C, 1, P]
    return out[:, :, 0].transpose(1, 2)


def _ray_diff(centers: Tensor, points: Tensor, directions: Tensor) -> Tensor:
    """[V, R, S, 4]: unit direction from each view centre [V, 3] to each point [R, S, 3], minus the query
    direction [R, 3], and the cosine between the two."""
    query = F.normalize(directions, dim=-1)[None, :, None, :]  # [1, R, 1, 3]
    ref = F.normalize(points[None] - centers[:, None, None, :], dim=-1)  # [V, R, S, 3]
    cos = (ref * query).sum(dim=-1, keepdim=True)  # [V, R, S, 1]
    return torch.cat([ref - query, cos], dim=-1)
