"""Projection of ray samples into every reference view: bilinear features and colours, validity, direction cues.

Layout: per-view tensors are channels-first [V, C, P] with P = R * S samples. It is what ``grid_sample`` returns,
so no transpose of the big per-view tensors is ever needed; reductions over views run along the first axis and
per-view linear layers are one batched matrix product ``W [O, C] @ x [V, C, P]``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.model.occlusion import visible
from insertnerf_cli.model.types import EncodedViews

# Grid coordinate given to samples a view cannot see: outside [-1, 1], so zero padding returns zeros for them.
_OUTSIDE = 4.0


@dataclass(frozen=True)
class Projected:
    """What each reference view sees of each of the P = R * S samples.

    Attributes:
        features: per scale (coarse to fine) [V, C_l, P] bilinear U-Net features, zero where invalid.
        colours: [V, 3, P] bilinear reference colours, zero where invalid: what the network reads (its inputs
            and the photo-consistency cue), at the size the references were encoded at, as in training.
        mask: [V, 1, P] 1 where the sample is in front of the view and inside its image, else 0.
        ray_diff: [V, 4, P] (unit ref direction - unit query direction, their cosine): how differently the
            view looks at the sample.
        finer: [V, 3, P] the same colours looked up in EncodedViews.colours (the photos at a finer size), or None
            where there are none; the output colour blends these (blend_colours).
        visible: [V, 1, P] ``mask`` less the views whose SfM points put a nearer surface in front of the sample
            (occlusion.visible), or None where the references carry no Occlusion. The choice of the views
            nearest in angle ranks the views that pass it first; ``unoccluded`` then makes it the mask.
    """

    features: tuple[Tensor, ...]
    colours: Tensor  # [V, 3, P]
    mask: Tensor  # [V, 1, P]
    ray_diff: Tensor  # [V, 4, P]
    finer: Tensor | None = None  # [V, 3, P]
    visible: Tensor | None = None  # [V, 1, P]

    @property
    def blend_colours(self) -> Tensor:
        """[V, 3, P] the reference colours the output colour blends: the finer lookup where there is one."""
        return self.colours if self.finer is None else self.finer

    @property
    def cos(self) -> Tensor:
        """[V, 1, P] cosine between the query ray and the view's ray through the sample."""
        return self.ray_diff[:, 3:]

    def nearest_in_angle(self, views: int) -> Projected:
        """Per sample, only the ``views`` views whose rays are closest in angle to the query ray: [K, C, P]
        tensors (K = views), the views that see the sample first (``visible`` where there is one, else ``mask``).
        With V <= K views this is ``self`` unchanged."""
        if self.mask.shape[0] <= views:
            return self
        # A view a nearer surface hides gives its place to the next one in angle, so that a sample keeps K views
        # that see it (a small gain at 16 views: docs/research-log.md, Reference views).
        seen = self.mask if self.visible is None else self.visible
        # The largest cosines are the smallest angles, without ray_angle's asin (a quarter of this call's time).
        cos = torch.where(seen > 0, self.cos, torch.full_like(seen, -2.0))  # [V, 1, P]; unseen: last
        # topk along a contiguous last axis: along the view axis of [V, 1, P] it measured 10x slower on CPU.
        index = cos[:, 0].T.contiguous().topk(views, dim=1).indices.T[:, None]  # [K, 1, P]

        def pick(x: Tensor) -> Tensor:  # [V, C, P] -> [K, C, P]
            return torch.gather(x, 0, index.expand(views, x.shape[1], x.shape[2]))

        return Projected(tuple(pick(f) for f in self.features), pick(self.colours), pick(self.mask),
                         pick(self.ray_diff), None if self.finer is None else pick(self.finer),
                         None if self.visible is None else pick(self.visible))

    def unoccluded(self) -> Projected:
        """These views with ``visible`` as their mask (``self`` where there is none)."""
        if self.visible is None:
            return self
        return replace(self, mask=self.visible, visible=None)


def ray_angle(ray_diff: Tensor) -> Tensor:
    """[V, 1, P] angle between each view's ray through the sample and the query ray, from ray_diff [V, 4, P].

    2 asin(|u - q| / 2) is the angle between unit vectors u and q, accurate where acos(cos) is not (angle ~ 0).
    """
    return 2.0 * torch.asin((_length(ray_diff[:, :3]) / 2.0).clamp(max=1.0))


def _length(vectors: Tensor) -> Tensor:
    """[V, 1, P] the Euclidean length of ``vectors`` [V, 3, P] along their middle axis.

    A sum of squares, not .norm(dim=1) or F.normalize(dim=1): reducing this 3-long middle axis, torch's norm took
    25-29 ms for [10, 3, 40000] on the CPU against 0.4-4 (docs/research-log.md, Speed), and every projection
    takes two of them.
    """
    return (vectors * vectors).sum(dim=1, keepdim=True).sqrt()


def projection_matrices(cameras: Cameras) -> Tensor:
    """K [R | t] [V, 3, 4] of each camera: homogeneous world point -> (u z, v z, z)."""
    return cameras.K @ cameras.w2c[:, :3, :]


def project_samples(encoded: EncodedViews, points: Tensor, directions: Tensor, finer: bool = True,
                    features: bool = True) -> Projected:
    """Sample every reference view at every point.

    Args:
        encoded: the encoded reference views (V).
        points: [R, S, 3] world positions of the samples.
        directions: [R, 3] query ray directions (any length).
        finer: also look the colours up in ``encoded.colours`` where it holds them (Projected.finer); False
            where no colour is blended (render's coarse pass).
        features: also the U-Net features (Projected.features); False gives () where only colours are read
            (prior_blend).
    """
    rays, samples = points.shape[:2]
    flat = points.reshape(rays * samples, 3).T  # [3, P]
    uv, depth = pixel_coordinates(encoded.projection.to(points), flat)
    valid = ((depth > 1e-6) & (uv[:, :1] >= 0) & (uv[:, :1] <= encoded.width)
             & (uv[:, 1:] >= 0) & (uv[:, 1:] <= encoded.height))  # [V, 1, P]
    pad_h, pad_w = encoded.padded_size
    grid = _grid(uv, valid, pad_w, pad_h)  # [V, 1, P, 2]
    looked_up = tuple(_sample(f, grid) for f in encoded.features) if features else ()
    centers = encoded.centers.to(points)
    fine = _finer_colours(encoded, uv, valid) if finer and encoded.colours is not None else None
    mask, ray_diff = valid.to(points.dtype), _ray_diff(centers, flat, directions, samples)
    seen = None if encoded.occlusion is None else \
        visible(encoded.occlusion, uv, depth, mask, ray_angle(ray_diff), encoded.width, encoded.height)
    return Projected(looked_up, _sample(encoded.images, grid), mask, ray_diff, fine, seen)


def _finer_colours(encoded: EncodedViews, uv: Tensor, valid: Tensor) -> Tensor:
    """[V, 3, P] reference colours at pixel positions uv [V, 2, P] (valid [V, 1, P]) in ``encoded.colours``, the
    photos at a finer size (which span the real image exactly, so the grid is relative to it; zero where invalid)."""
    return _sample(encoded.colours, _grid(uv, valid, encoded.width, encoded.height))


def _grid(uv: Tensor, valid: Tensor, width: float, height: float) -> Tensor:
    """[V, 1, P, 2] grid_sample coordinates of pixel positions uv [V, 2, P] in an image that ``width`` x
    ``height`` pixels span; _OUTSIDE where not ``valid`` [V, 1, P]."""
    # align_corners=False: -1 and +1 are the image's outer edges, matching pixel (0, 0) = [0, 1]^2.
    scale = torch.tensor([2.0 / width, 2.0 / height], dtype=uv.dtype, device=uv.device)[:, None]
    return torch.where(valid, uv * scale - 1.0, torch.full_like(uv, _OUTSIDE)).transpose(1, 2)[:, None]


def pixel_coordinates(projection: Tensor, points: Tensor) -> tuple[Tensor, Tensor]:
    """Pixel positions uv [V, 2, P] and camera depths [V, 1, P] of points [3, P] under K [R | t] [V, 3, 4]
    (projection_matrices); uv is meaningless where the depth is not positive."""
    pix = projection[:, :, :3] @ points + projection[:, :, 3:]  # [V, 3, P]
    depth = pix[:, 2:]
    return pix[:, :2] / depth.clamp(min=1e-6), depth


def _sample(maps: Tensor, grid: Tensor) -> Tensor:
    """Bilinear lookup of maps [V, C, h, w] at grid [V, 1, P, 2] -> [V, C, P] (zeros outside)."""
    return F.grid_sample(maps, grid, mode="bilinear", padding_mode="zeros", align_corners=False)[:, :, 0]


def _ray_diff(centers: Tensor, points: Tensor, directions: Tensor, samples: int) -> Tensor:
    """[V, 4, P]: unit direction from each view centre [V, 3] to each point [3, P], minus the query direction
    ([R, 3], repeated for the S samples of each ray), and the cosine between the two."""
    query = F.normalize(directions, dim=-1).repeat_interleave(samples, dim=0).T[None]  # [1, 3, P]
    offset = points[None] - centers[:, :, None]  # [V, 3, P]
    ref = offset / _length(offset).clamp(min=1e-12)  # F.normalize's floor
    cos = (ref * query).sum(dim=1, keepdim=True)  # [V, 1, P]
    return torch.cat([ref - query, cos], dim=1)
