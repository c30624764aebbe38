"""Where along each ray the field is evaluated: stratified coarse samples and importance-sampled fine samples.

Samples come with their bin edges: compositing (render.py) integrates density over each bin, so a sample's
weight depends on the width of the interval it stands for, not on the gap to its neighbour.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import check_shape
from insertnerf_cli.cameras.rays import Rays


@dataclass(frozen=True)
class RaySamples:
    """S samples on each of R rays.

    Attributes:
        t: [R, S] sorted sample depths (ray parameter = camera depth).
        edges: [R, S + 1] sorted bin edges; sample k stands for the interval [edges[k], edges[k+1]].
    """

    t: Tensor  # [R, S]
    edges: Tensor  # [R, S + 1]

    def __post_init__(self) -> None:
        check_shape("edges", self.edges, (self.t.shape[0], self.t.shape[1] + 1))

    def points(self, rays: Rays) -> Tensor:
        """World positions [R, S, 3] of the samples."""
        return rays.origins[:, None, :] + self.t[..., None] * rays.directions[:, None, :]


def stratified_samples(rays: Rays, count: int, jitter: bool, in_disparity: bool = False) -> RaySamples:
    """``count`` bins evenly spaced in t (or in 1/t) over [near, far]; one sample per bin.

    Args:
        rays: R rays.
        count: S, samples per ray.
        jitter: a uniform random position inside each bin (training) instead of its centre (evaluation).
        in_disparity: space the bins evenly in inverse depth, which suits forward-facing scenes with far content.
    Returns:
        RaySamples with t [R, S] and edges [R, S + 1].
    """
    near, far = rays.near[:, None], rays.far[:, None]  # [R, 1]
    steps = torch.linspace(0.0, 1.0, count + 1, dtype=near.dtype, device=near.device)  # [S+1]
    if in_disparity:
        edges = 1.0 / (1.0 / near * (1.0 - steps) + 1.0 / far * steps)  # [R, S+1]
    else:
        edges = near + (far - near) * steps  # [R, S+1]
    if jitter:
        u = torch.rand(edges.shape[0], count, dtype=edges.dtype, device=edges.device)
    else:
        u = torch.full((edges.shape[0], count), 0.5, dtype=edges.dtype, device=edges.device)
    t = edges[:, :-1] + (edges[:, 1:] - edges[:, :-1]) * u  # [R, S]
    return RaySamples(t, edges)


def importance_samples(coarse: RaySamples, weights: Tensor, count: int, jitter: bool,
                       near: Tensor, far: Tensor) -> RaySamples:
    """Draw ``count`` samples per ray from the piecewise-constant pdf that the coarse weights put on their bins.

    Args:
        coarse: the coarse samples (their edges define the pdf's bins).
        weights: [R, S] coarse compositing weights (detached here: the fine pass must not steer the coarse one).
        count: S', fine samples per ray.
        jitter: random sorted u (training) or evenly spaced u (evaluation).
        near, far: [R] ray bounds; the fine bins are clamped into them.
    Returns:
        RaySamples with t [R, S'] sorted and edges [R, S' + 1] halfway between neighbours.
    """
    check_shape("weights", weights, coarse.t.shape)
    # A small floor keeps the pdf defined on empty rays and still sends a few samples everywhere.
    pdf = weights.detach() + 1e-5  # [R, S]
    pdf = pdf / pdf.sum(dim=-1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, dim=-1)], dim=-1).clamp(max=1.0)  # [R, S+1]
    rays = weights.shape[0]
    if jitter:
        u = torch.sort(torch.rand(rays, count, dtype=pdf.dtype, device=pdf.device), dim=-1).values  # [R, S']
    else:
        u = ((torch.arange(count, dtype=pdf.dtype, device=pdf.device) + 0.5) / count).expand(rays, count)
    t = _invert_cdf(cdf, coarse.edges.detach(), u.contiguous())  # [R, S']
    return RaySamples(t, _edges_around(t, near, far))


def _invert_cdf(cdf: Tensor, edges: Tensor, u: Tensor) -> Tensor:
    """Positions [R, S'] where the piecewise-linear cdf [R, S+1] over ``edges`` [R, S+1] reaches u [R, S']."""
    last = cdf.shape[-1] - 1
    above = torch.searchsorted(cdf, u, right=True).clamp(1, last)  # [R, S']
    below = above - 1
    cdf_lo, cdf_hi = cdf.gather(-1, below), cdf.gather(-1, above)
    edge_lo, edge_hi = edges.gather(-1, below), edges.gather(-1, above)
    frac = ((u - cdf_lo) / (cdf_hi - cdf_lo).clamp(min=1e-8)).clamp(0.0, 1.0)
    return edge_lo + frac * (edge_hi - edge_lo)


def _edges_around(t: Tensor, near: Tensor, far: Tensor) -> Tensor:
    """Bin edges [R, S+1] for sorted samples t [R, S]: midpoints inside, mirrored half-gaps at the ends."""
    mid = 0.5 * (t[:, 1:] + t[:, :-1])  # [R, S-1]
    if mid.shape[1] == 0:
        return torch.stack([near, far], dim=-1).to(t)
    first = 2.0 * t[:, :1] - mid[:, :1]
    last = 2.0 * t[:, -1:] - mid[:, -1:]
    edges = torch.cat([first, mid, last], dim=-1)  # [R, S+1]
    return torch.maximum(torch.minimum(edges, far[:, None]), near[:, None])
