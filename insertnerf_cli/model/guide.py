"""Fine samples sent toward a known depth: the coarse weights with a share moved to a band around it.

The coarse pass finds surfaces by matching the references, which on real photos leaves much of its weight off the
surface. Where a depth is known at a pixel (the scene's SfM points, sfm/depth_prior.py), a share of the fine
samples goes to a narrow band around it and the rest stays where the coarse pass put them, so the fine pass sees
both candidates and its densities decide (measured: docs/research-log.md, Sampling and the SfM depth prior).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import check_shape


@dataclass(frozen=True)
class GuideOptions:
    """How the fine samples follow a known depth.

    Attributes:
        share: the part of each ray's fine-sample pdf moved to the band (the rest keeps the coarse weights, which
            a wrong depth would otherwise take from the surface entirely).
        width: the band's standard deviation as a fraction of its depth.
    """

    share: float = 0.75
    width: float = 0.05

    def __post_init__(self) -> None:
        if not (0.0 <= self.share <= 1.0 and self.width > 0.0):
            raise ValueError(f"share must lie in [0, 1] and width be positive, got {self}")

    @property
    def band_reach(self) -> float:
        """A far bound this factor past a depth holds its band (two widths)."""
        return 1.0 + 2.0 * self.width


def guide_weights(weights: Tensor, t: Tensor, prior: Tensor, options: GuideOptions = GuideOptions()) -> Tensor:
    """[R, S] coarse weights with ``options.share`` of each ray's total moved to a Gaussian of relative
    ``options.width`` around its ``prior`` depth [R] (on the sample depths t [R, S]); rays without a prior (NaN)
    or whose band holds no sample keep their weights. The total per ray is kept, so what reads the opacity is
    unchanged."""
    check_shape("t", t, weights.shape)
    check_shape("prior", prior, (weights.shape[0],))
    z = prior.to(weights)[:, None]  # [R, 1]
    band = torch.exp(-0.5 * ((t - z) / (options.width * z)) ** 2)
    mass = band.sum(dim=-1, keepdim=True)
    usable = torch.isfinite(z) & (mass > 1e-12)  # [R, 1]
    share = options.share
    guided = (1.0 - share) * weights + share * band / mass.clamp(min=1e-12) * weights.sum(dim=-1, keepdim=True)
    return torch.where(usable, guided, weights)
