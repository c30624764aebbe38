"""Geometry supervision of the compositing weights: where the weight mass of a ray should sit.

Two terms, both on the weights w [R, S] of a pass and its bins (edges [R, S + 1]):
- depth: synth writes the exact z-depth of every pixel, so the weight mass should sit in the bin that holds the
  true depth, as NeuRay does with its depth supervision. The term is sum_k w_k d_k + (1 - sum_k w_k), d_k the
  log-depth distance from the true depth to bin k (0 in the bin that holds it): zero exactly when every weight
  sits in that bin, positive otherwise, and the rest of an opaque ray's mass counts fully. A ray that sees no
  surface (depth 0: a sky or the plain backdrop) should be empty: its term is its opacity.
- distortion (mip-NeRF 360): sum_ij w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 (s_i+1 - s_i), on the bin midpoints
  m and edges s normalised to [0, 1] in the sampling's own spacing; small when the mass is one compact peak,
  large for floaters and haze spread along the ray.
Scenes without depth (real captures, finetune) carry NaN depths: those rays add nothing to the depth term.
"""
from __future__ import annotations

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import check_shape

NO_SURFACE = 0.0  # synth's depth files say "no surface" with 0


def depth_loss(weights: Tensor, edges: Tensor, depth: Tensor) -> Tensor:
    """Mean depth term over the rays with a known depth, or 0 when none has one.

    Args:
        weights: [R, S] compositing weights of one pass.
        edges: [R, S + 1] its bin edges in t (camera z, since ray directions have camera-z = 1).
        depth: [R] true z-depth: > 0 a surface, 0 no surface, NaN unknown.
    """
    check_shape("edges", edges, (weights.shape[0], weights.shape[1] + 1))
    check_shape("depth", depth, (weights.shape[0],))
    known = torch.isfinite(depth)
    surface = known & (depth > NO_SURFACE)
    safe = torch.where(surface, depth, torch.ones_like(depth))[:, None]  # [R, 1], log-safe
    log_edges = torch.log(edges.clamp(min=1e-6))
    below = log_edges[:, :-1] - torch.log(safe)  # [R, S] > 0 when the bin starts beyond the true depth
    above = torch.log(safe) - log_edges[:, 1:]  # [R, S] > 0 when the bin ends before it
    distance = torch.clamp(torch.maximum(below, above), min=0.0)  # [R, S] 0 in the bin that holds the depth
    opacity = weights.sum(dim=-1)  # [R]
    per_ray = torch.where(surface, (weights * distance).sum(dim=-1) + (1.0 - opacity), opacity)
    count = known.sum()
    return torch.where(known, per_ray, torch.zeros_like(per_ray)).sum() / count.clamp(min=1)


def distortion_loss(weights: Tensor, edges: Tensor, near: Tensor, far: Tensor, in_disparity: bool) -> Tensor:
    """Mean mip-NeRF 360 distortion of R rays' weights [R, S] on bins ``edges`` [R, S + 1] within near/far [R]."""
    check_shape("edges", edges, (weights.shape[0], weights.shape[1] + 1))
    near, far = near[:, None], far[:, None]
    if in_disparity:
        s = (1.0 / near - 1.0 / edges) / (1.0 / near - 1.0 / far).clamp(min=1e-8)
    else:
        s = (edges - near) / (far - near).clamp(min=1e-8)  # [R, S + 1] in [0, 1]
    mid = 0.5 * (s[:, 1:] + s[:, :-1])  # [R, S]
    width = s[:, 1:] - s[:, :-1]
    pairwise = (weights[:, :, None] * weights[:, None, :] * (mid[:, :, None] - mid[:, None, :]).abs()).sum((1, 2))
    return (pairwise + (weights ** 2 * width).sum(dim=-1) / 3.0).mean()
