"""Fine samples guided in training as render guides them by SfM points (model.guide.guide_weights).

Render and eval send most fine samples to a band around the depth of the scene's SfM points; placed by the
coarse weights alone in training, the fine pass would never see the sample layout it renders with. A synth scene's
exact depth stands in for the points, spoilt the way a splatted sparse cloud is (docs/research-log.md, Sampling and
the SfM depth prior): no point on empty backdrop or sky, gaps where no feature was found, a few percent of depth
error, and some pixels that carry a wrong neighbour's depth (a splat bleeding across an occlusion edge).
"""
from __future__ import annotations

import torch
from torch import Tensor

from insertnerf_cli.model.geometry_losses import NO_SURFACE

# Shares of the rays with a surface that get a prior, and of those that get a wrong one; the prior's relative
# error. A real capture's points cover most textured pixels within 12 px of a splat, and triangulation on a synth
# scene has a median relative error near 3 % (measured: docs/research-log.md, Sampling and the SfM depth prior).
COVERAGE = 0.7
WRONG = 0.1
RELATIVE_ERROR = 0.03


def simulated_prior(depth: Tensor) -> Tensor:
    """[R] a sparse-point depth prior of R rays from their true depths [R] (> 0 a surface, 0 none, NaN unknown):
    NaN where a ray gets none. Draws from torch's generator of the depth's device (a checkpoint holds its state)."""
    surface = torch.nan_to_num(depth, nan=NO_SURFACE) > NO_SURFACE
    keep = surface & (torch.rand(depth.shape, device=depth.device) < COVERAGE)
    noisy = depth * torch.exp(RELATIVE_ERROR * torch.randn(depth.shape, device=depth.device))
    # A wrong prior: the depth of another ray of the same batch that hit a surface (its own when none did). The
    # nonzero is one host sync a step: the guided GPU runs made 15.5-15.7k rays/s beside the control's 16.7k.
    donors = torch.nonzero(surface).flatten()
    if len(donors):
        other = depth[donors[torch.randint(len(donors), depth.shape, device=depth.device)]]
        wrong = torch.rand(depth.shape, device=depth.device) < WRONG
        noisy = torch.where(wrong, other, noisy)
    return torch.where(keep, noisy, torch.full_like(depth, float("nan")))
