"""Volume compositing: densities on bins -> weights -> rgb, depth and opacity of each ray.

It sits below the model (model/ composites its passes with it) and below render.py (which renders whole frames
through the model), so neither imports the other in a circle.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import check_shape


@dataclass(frozen=True)
class Composite:
    """One volume-rendering pass over R rays of S samples.

    Attributes:
        rgb: [R, 3] colour composited over the background.
        depth: [R] median depth of the visible content (median_depth; stays within [near, far]).
        opacity: [R] sum of the weights, in [0, 1].
        weights: [R, S] compositing weights w_k = T_k (1 - exp(-sigma_k delta_k)).
        t: [R, S] sample depths the weights belong to.
    """

    rgb: Tensor  # [R, 3]
    depth: Tensor  # [R]
    opacity: Tensor  # [R]
    weights: Tensor  # [R, S]
    t: Tensor  # [R, S]


def composite_weights(density: Tensor, edges: Tensor, ray_scale: Tensor) -> Tensor:
    """Weights [R, S] from densities [R, S] on bins with ``edges`` [R, S + 1] in t.

    ``ray_scale`` [R] converts a step in t into world distance (|d|, since directions have camera-z = 1), so the
    density is per world unit whatever the ray's angle. Transmittance is exp(-cumsum) of the optical depth of the
    bins before each sample, which is stabler than a cumulative product of (1 - alpha).
    """
    check_shape("edges", edges, (density.shape[0], density.shape[1] + 1))
    delta = (edges[:, 1:] - edges[:, :-1]) * ray_scale[:, None]  # [R, S]
    optical = density * delta  # [R, S]
    alpha = 1.0 - torch.exp(-optical)
    before = torch.cumsum(optical, dim=-1) - optical  # exclusive cumsum [R, S]
    return alpha * torch.exp(-before)


def composite(weights: Tensor, colour: Tensor, t: Tensor, background: Tensor) -> Composite:
    """Composite per-sample colours [R, S, 3] with weights [R, S] over ``background`` [3] (or [R, 3])."""
    opacity = weights.sum(dim=-1)  # [R]
    rgb = torch.einsum("rs,rsc->rc", weights, colour) + (1.0 - opacity)[:, None] * background  # [R, 3]
    # An empty ray falls back to its mean sample. Unconditional: a test of any() would sync the host with the
    # device on every composite.
    depth = torch.where(opacity < 1e-6, t.mean(dim=-1), median_depth(weights, t))
    return Composite(rgb=rgb, depth=depth, opacity=opacity, weights=weights, t=t)


def median_depth(weights: Tensor, t: Tensor) -> Tensor:
    """[R] the depth at which the weights [R, S] on sorted samples t [R, S] reach half their sum.

    Each weight sits at its sample, half of it counted before and half after, and the running sum goes linearly
    between samples: one opaque sample gives its own t, two equal ones their midpoint, and the depth moves
    smoothly as weight shifts. Unlike the weighted mean, a tail of weight far behind a surface (a reflection's
    virtual depth, a faint floater) does not drag the depth off the surface: 10-35 % less error on synth scenes
    and SfM points (docs/research-log.md, Sampling and the SfM depth prior).
    """
    if t.shape[-1] == 1:
        return t[:, 0]
    running = torch.cumsum(weights, dim=-1) - 0.5 * weights  # [R, S], non-decreasing
    half = 0.5 * weights.sum(dim=-1, keepdim=True)  # [R, 1]
    # running[0] <= half <= running[-1] always, so the crossing lies between samples k - 1 and k.
    k = torch.searchsorted(running.contiguous(), half.contiguous()).clamp(1, t.shape[-1] - 1)  # [R, 1]
    lo, hi = running.gather(-1, k - 1), running.gather(-1, k)
    share = ((half - lo) / (hi - lo).clamp(min=1e-12)).clamp(0.0, 1.0)
    t_lo = t.gather(-1, k - 1)
    return (t_lo + share * (t.gather(-1, k) - t_lo)).squeeze(-1)
