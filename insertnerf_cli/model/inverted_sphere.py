"""NeRF++'s split of space (docs/method.md, The NeRF++ backbone): a foreground inside a sphere that holds the
cameras and the subject, and a background outside it, addressed by inverted-sphere coordinates.

A point p outside the sphere of centre c and radius r, at x = (p - c) / r with q = |x| >= 1, is
(x / q, 1 / q): a direction on the unit sphere and an inverse distance in (0, 1]. Every point out to infinity
then lies in a bounded 4-D set, and the background field samples a ray evenly in 1 / q, so that far content gets
as many samples as near content gets per unit of parallax.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import check_shape
from insertnerf_cli.cameras.rays import Rays

# The background's farthest sample, in inverse distance: 1e4 radii away a point projects into a view at its
# direction's vanishing point to well under a pixel, and its coordinates still fit float32 (1 / q = 0 exactly
# would put it at infinity, which a projection cannot reach with finite coordinates).
MIN_INVERSE_DISTANCE = 1e-4


@dataclass(frozen=True)
class Sphere:
    """The foreground's bound: centre [3] and radius (a 0-d tensor), in the scene's world."""

    centre: Tensor  # [3]
    radius: Tensor  # []

    def __post_init__(self) -> None:
        check_shape("centre", self.centre, (3,))
        check_shape("radius", self.radius, ())


def inverted_sphere(points: Tensor, sphere: Sphere) -> Tensor:
    """[..., 4] (x / q, 1 / q) of points [..., 3] at x = (p - c) / r, q = |x| (taken as at least 1: a point inside
    the sphere maps onto its surface)."""
    x = (points - sphere.centre) / sphere.radius
    q = x.norm(dim=-1, keepdim=True)
    return torch.cat([x / q.clamp_min(1e-12), 1.0 / q.clamp_min(1.0)], dim=-1)


def from_inverted(coords: Tensor, sphere: Sphere) -> Tensor:
    """[..., 3] the world points of inverted-sphere coordinates [..., 4] (the inverse of inverted_sphere outside
    the sphere); 1 / q must be positive."""
    return sphere.centre + sphere.radius * coords[..., :3] / coords[..., 3:]


@dataclass(frozen=True)
class BackgroundSamples:
    """S samples on each of R rays outside the sphere, evenly spaced in inverse distance.

    Attributes:
        inverse: [R, S] 1 / q of each sample, decreasing (near to far).
        edges: [R, S + 1] bin edges in 1 / q, from 1 (the sphere) down to MIN_INVERSE_DISTANCE; a bin's width in
            1 / q is the step its density is integrated over (NeRF++'s background measure).
        t: [R, S] each sample's ray parameter (camera depth).
    """

    inverse: Tensor
    edges: Tensor
    t: Tensor

    def points(self, rays: Rays) -> Tensor:
        """[R, S, 3] world positions."""
        return rays.origins[:, None, :] + self.t[..., None] * rays.directions[:, None, :]


def background_samples(rays: Rays, sphere: Sphere, count: int, jitter: bool) -> BackgroundSamples:
    """``count`` bins evenly spaced in 1 / q from the sphere out to MIN_INVERSE_DISTANCE, one sample per bin (a
    random place in it when ``jitter``, else its middle), each placed where its ray reaches distance r / (1 / q)
    from the centre."""
    steps = torch.linspace(1.0, MIN_INVERSE_DISTANCE, count + 1, dtype=rays.origins.dtype, device=rays.origins.device)
    edges = steps.expand(len(rays), count + 1)
    share = torch.rand(len(rays), count, dtype=edges.dtype, device=edges.device) if jitter else \
        torch.full((len(rays), count), 0.5, dtype=edges.dtype, device=edges.device)
    inverse = edges[:, :-1] + (edges[:, 1:] - edges[:, :-1]) * share
    return BackgroundSamples(inverse, edges, _reach(rays, sphere, inverse))


def _reach(rays: Rays, sphere: Sphere, inverse: Tensor) -> Tensor:
    """[R, S] the t at which each ray is r / inverse from the centre (the far crossing of that larger sphere)."""
    offset = rays.origins - sphere.centre
    a = (rays.directions * rays.directions).sum(dim=-1, keepdim=True)  # [R, 1]
    b = (rays.directions * offset).sum(dim=-1, keepdim=True)
    c = (offset * offset).sum(dim=-1, keepdim=True) - (sphere.radius / inverse) ** 2  # [R, S]
    return (-b + (b * b - a * c).clamp_min(0.0).sqrt()) / a
