"""Multi-layer dynamic-static (MLDS) aggregation: per feature scale, many views of a sample -> one descriptor.

Per scale l (paper section 3.2; docs/method.md, Aggregation):
  1. dynamic weights M_dy = softmax over valid views of an MLP on [f_n, maxpool_n f, ray-direction difference]
     and, with the visibility cue, |f_n - mean_n f|: a view that sees another surface in front of the sample
     disagrees with the others there, and the cue lets the MLP take its weight away (IBRNet's and NeuRay's idea);
  2. weighted mean and variance of the features under M_dy;
  3. [f_n, mean, var] per view -> half width (the "halving" projection);
  4. static IBRNet-style weights exp(|s| (cos - 1)), min-shifted and normalised over valid views;
  5. output: mean and variance of the halved features under M_st, their max over valid views (the max branch),
     and the fraction of views that see the sample.

Per-view tensors are channels-first [V, C, P] (P samples); see projection.py. Inputs are non-negative and zero
for invalid views (U-Net features end in a ReLU, colours are in [0, 1], projection zeroes what a view cannot see),
so a plain max over views is the max over valid views, with no masking pass over the big tensors.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from insertnerf_cli.model.projection import ray_angle

# Radians: below a thousandth of a pixel's angle at any usable resolution; keeps 1 / angle finite.
_MIN_ANGLE = 1e-6
# Where fewer views than K see a sample, the lumigraph's cut-off angle a_K is this many times the widest angle
# among those that do: past 1, so that even the widest keeps a share of the weight.
FEWER_VIEWS_CUTOFF = 1.5


def channel_linear(layer: nn.Linear, x: Tensor, add: Tensor | None = None) -> Tensor:
    """Apply ``layer`` along the channel axis of x [V, C, P] -> [V, O, P], plus ``add`` (broadcast to it) if given.

    An explicit bmm over the expanded weight: ``weight @ x`` broadcasts by transposing x to [V * P, C] first,
    which measured 3-5x slower forward and backward on CPU. The bias and ``add`` enter through baddbmm's input,
    so the per-view tensor is written once instead of once per addition (these ops are memory-bound).
    """
    weight = layer.weight.expand(x.shape[0], -1, -1)
    offset = add
    if layer.bias is not None:
        offset = layer.bias[:, None] if offset is None else offset + layer.bias[:, None]
    return torch.bmm(weight, x) if offset is None else torch.baddbmm(offset, weight, x)


def masked_softmax(logits: Tensor, mask: Tensor, dim: int = 0) -> Tensor:
    """Softmax of logits over ``dim`` restricted to mask == 1; all-invalid slices give all-zero weights."""
    top = torch.where(mask > 0, logits, torch.full_like(logits, -1e4)).amax(dim=dim, keepdim=True).detach()
    weights = torch.exp((logits - top).clamp(max=0.0)) * mask
    return weights / weights.sum(dim=dim, keepdim=True).clamp(min=1e-8)


def weighted_moments(values: Tensor, weights: Tensor) -> tuple[Tensor, Tensor]:
    """Mean and variance over views (dim 0) of values [V, C, P] under weights [V, 1, P] summing to 1 (or 0).

    The variance is E[x^2] - E[x]^2, one pass fewer over the per-view tensor than E[(x - E[x])^2].
    """
    weighted = values * weights  # [V, C, P], reused for the second moment: one pass fewer over the big tensor
    mean = weighted.sum(dim=0, keepdim=True)  # [1, C, P]
    second = (weighted * values).sum(dim=0, keepdim=True)
    return mean, (second - mean * mean).clamp(min=0.0)


def angular_prior(ray_diff: Tensor, mask: Tensor, views: int, angle: Tensor | None = None) -> Tensor:
    """Unstructured-lumigraph view weights [V, 1, P] (Buehler et al. 2001) from ray_diff [V, 4, P], mask [V, 1, P]
    (``angle``: ray_angle(ray_diff) [V, 1, P] where the caller already has it, for priors of several K).

    A view's weight is (1 - a / a_K) / a, a the angle between its ray through the sample and the query ray, a_K
    the ``views``-th smallest angle among the views that see the sample: the nearest views in angle dominate and
    the K-th and farther get none, whatever the capture's spread (forward-facing grids differ by a degree, orbits
    by tens). Where fewer than K views see the sample, a_K is FEWER_VIEWS_CUTOFF x their largest angle,
    so each keeps a share.
    Learned weights are near-uniform on real photos (docs/research-log.md, Reference views): without this, every
    added view pulls a pixel's colour toward what the farther views see. Cameras only, so no gradient.
    """
    with torch.no_grad():
        angle = ray_angle(ray_diff) if angle is None else angle  # [V, 1, P]
        unseen = torch.full_like(angle, 2.0 * math.pi)  # larger than any angle: never among the K nearest
        angle = torch.where(mask > 0, angle, unseen)
        count = min(views, angle.shape[0])
        # topk along a contiguous last axis: along the view axis of [V, 1, P] it measured 10x slower on CPU.
        kth = angle[:, 0].T.contiguous().topk(count, dim=1, largest=False).values[:, -1][None, None]  # [1, 1, P]
        widest = torch.where(mask > 0, angle, torch.zeros_like(angle)).amax(dim=0, keepdim=True)
        fewer = mask.sum(dim=0, keepdim=True) < views
        kth = torch.where(fewer, FEWER_VIEWS_CUTOFF * widest, kth).clamp(min=_MIN_ANGLE)
        # A view on the query ray itself (angle 0) takes (almost) all the weight, as it should.
        prior = (1.0 - angle / kth).clamp(min=0.0) / (angle + _MIN_ANGLE) * mask
        return prior / prior.sum(dim=0, keepdim=True).clamp(min=1e-12)


def reweigh(weights: Tensor, prior: Tensor) -> Tensor:
    """weights [V, 1, P] times prior [V, 1, P], renormalised over views (all-zero slices stay zero)."""
    product = weights * prior
    return product / product.sum(dim=0, keepdim=True).clamp(min=1e-12)


class ScaleAggregator(nn.Module):
    """MLDS aggregation of one feature scale.

    Args:
        in_dim: C, per-view input width.
        half_dim: width after the halving projection.
        hidden: hidden width of the dynamic-weight MLP.
        sharpness_init: initial s of the static weights exp(|s| (cos - 1)).
        visibility: feed each view's deviation from the plain mean over views to the dynamic weights.
    """

    def __init__(self, in_dim: int, half_dim: int, hidden: int, sharpness_init: float,
                 visibility: bool = False) -> None:
        super().__init__()
        # Linear layers on [per-view, per-sample] inputs are split, so the per-sample part is computed once
        # per sample instead of once per view: the same function with V times fewer multiply-adds for it.
        self.dynamic_view = nn.Linear(in_dim, hidden)
        self.dynamic_direction = nn.Linear(4, hidden, bias=False)
        self.dynamic_pool = nn.Linear(in_dim, hidden, bias=False)
        self.dynamic_out = nn.Linear(hidden, 1)
        self.dynamic_deviation = None
        if visibility:
            # Zero at the start: a model warm-started from one without the cue begins as exactly that model.
            self.dynamic_deviation = nn.Linear(in_dim, hidden, bias=False)
            nn.init.zeros_(self.dynamic_deviation.weight)
        self.halve_view = nn.Linear(in_dim, half_dim)
        self.halve_moments = nn.Linear(2 * in_dim, half_dim, bias=False)
        self.sharpness = nn.Parameter(torch.tensor(float(sharpness_init)))
        self.out_dim = 3 * half_dim + 1

    def forward(self, features: Tensor, mask: Tensor, ray_diff: Tensor) -> tuple[Tensor, Tensor]:
        """features [V, C, P] (>= 0, zero where invalid), mask [V, 1, P], ray_diff [V, 4, P] ->
        (descriptor [P, out_dim], dynamic weights [V, 1, P])."""
        pooled = features.amax(dim=0, keepdim=True)  # [1, C, P]
        per_sample = channel_linear(self.dynamic_pool, pooled)  # [1, h, P]
        per_view = channel_linear(self.dynamic_direction, ray_diff, per_sample)  # [V, h, P]
        if self.dynamic_deviation is not None:
            plain = features.sum(dim=0, keepdim=True) / mask.sum(dim=0, keepdim=True).clamp(min=1.0)  # [1, C, P]
            per_view = channel_linear(self.dynamic_deviation, (features - plain).abs() * mask, per_view)
        hidden = F.relu(channel_linear(self.dynamic_view, features, per_view))  # [V, h, P]
        dynamic = masked_softmax(channel_linear(self.dynamic_out, hidden), mask)  # [V, 1, P]
        mean, var = weighted_moments(features, dynamic)  # [1, C, P] each
        moments = channel_linear(self.halve_moments, torch.cat([mean, var], dim=1))  # [1, C/2, P]
        halved = F.relu(channel_linear(self.halve_view, features, moments)) * mask  # [V, C/2, P]
        static = self.static_weights(ray_diff[:, 3:], mask)  # [V, 1, P]
        s_mean, s_var = weighted_moments(halved, static)
        seen = mask.mean(dim=0, keepdim=True)  # [1, 1, P]
        out = torch.cat([s_mean, s_var, halved.amax(dim=0, keepdim=True), seen], dim=1)  # [1, out_dim, P]
        return out[0].T, dynamic

    def static_weights(self, cos: Tensor, mask: Tensor) -> Tensor:
        """IBRNet's view weights [V, 1, P] from cos [V, 1, P]: views looking along the query ray weigh more.

        The minimum over valid views is subtracted before normalising, so the worst valid view gets (almost)
        no weight; a small floor keeps ties (e.g. a single valid view) at uniform weights.
        """
        raw = torch.exp(self.sharpness.abs() * (cos - 1.0)) * mask
        floor = (raw + (1.0 - mask) * 2.0).amin(dim=0, keepdim=True)  # min over valid views (raw <= 1)
        shifted = ((raw - floor).clamp(min=0.0) + 1e-4) * mask
        return shifted / shifted.sum(dim=0, keepdim=True).clamp(min=1e-8)
