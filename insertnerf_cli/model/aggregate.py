"""Multi-layer dynamic-static (MLDS) aggregation: per feature scale, many views of a sample -> one descriptor.

Per scale l (paper section 3.2, method.md section 7.2-7.3):
  1. dynamic weights M_dy = softmax over valid views of an MLP on [f_n, maxpool_n f];
  2. weighted mean and variance of the features under M_dy;
  3. [f_n, mean, var] per view -> half width (the "halving" projection);
  4. static IBRNet-style weights exp(|s| (cos - 1)), min-shifted and normalised over valid views;
  5. output: mean and variance of the halved features under M_st, their max over views, and the fraction of
     views that see the sample.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

# Features of invalid views are pushed this far down before a max over views, so they never win.
_MASKED = -1e4


def masked_softmax(logits: Tensor, mask: Tensor, dim: int = 0) -> Tensor:
    """Softmax of logits over ``dim`` restricted to mask == 1; all-invalid slices give all-zero weights."""
    shifted = logits - logits.masked_fill(mask == 0, _MASKED).amax(dim=dim, keepdim=True).detach()
    weights = torch.exp(shifted.clamp(max=0.0)) * mask
    return weights / weights.sum(dim=dim, keepdim=True).clamp(min=1e-8)


def weighted_moments(values: Tensor, weights: Tensor) -> tuple[Tensor, Tensor]:
    """Mean and variance over views (dim 0) of values [V, R, S, C] under weights [V, R, S, 1] summing to <= 1."""
    mean = (values * weights).sum(dim=0, keepdim=True)  # [1, R, S, C]
    var = ((values - mean) ** 2 * weights).sum(dim=0, keepdim=True)
    return mean, var


def masked_max(values: Tensor, mask: Tensor) -> Tensor:
    """Max over views (dim 0) of values [V, R, S, C] among valid views; 0 where no view is valid."""
    best = (values + (1.0 - mask) * _MASKED).amax(dim=0, keepdim=True)  # [1, R, S, C]
    return best * (mask.amax(dim=0, keepdim=True) > 0)


class ScaleAggregator(nn.Module):
    """MLDS aggregation of one feature scale.

    Args:
        in_dim: C, per-view input width (U-Net features + colour).
        half_dim: width after the halving projection.
        hidden: hidden width of the dynamic-weight MLP.
        sharpness_init: initial s of the static weights exp(|s| (cos - 1)).
    """

    def __init__(self, in_dim: int, half_dim: int, hidden: int, sharpness_init: float) -> None:
        super().__init__()
        self.direction = nn.Linear(4, in_dim)
        # Linear layers on [per-view, per-sample] inputs are split in two, so the per-sample half is computed
        # once per sample instead of once per view: same function, V times fewer multiply-adds for that half.
        self.dynamic_view = nn.Linear(in_dim, hidden)
        self.dynamic_pool = nn.Linear(in_dim, hidden, bias=False)
        self.dynamic_out = nn.Linear(hidden, 1)
        self.halve_view = nn.Linear(in_dim, half_dim)
        self.halve_moments = nn.Linear(2 * in_dim, half_dim, bias=False)
        self.sharpness = nn.Parameter(torch.tensor(float(sharpness_init)))
        self.out_dim = 3 * half_dim + 1

    def forward(self, features: Tensor, mask: Tensor, ray_diff: Tensor) -> tuple[Tensor, Tensor]:
        """features [V, R, S, C], mask [V, R, S, 1], ray_diff [V, R, S, 4] ->
        (descriptor [R, S, out_dim], dynamic weights [V, R, S, 1])."""
        f = (features + self.direction(ray_diff)) * mask  # [V, R, S, C]
        pooled = masked_max(f, mask)  # [1, R, S, C]
        logits = self.dynamic_out(F.relu(self.dynamic_view(f) + self.dynamic_pool(pooled)))  # [V, R, S, 1]
        dynamic = masked_softmax(logits, mask)
        mean, var = weighted_moments(f, dynamic)  # [1, R, S, C] each
        halved = F.relu(self.halve_view(f) + self.halve_moments(torch.cat([mean, var], dim=-1)))  # [V, R, S, C/2]
        static = self.static_weights(ray_diff[..., 3:], mask)  # [V, R, S, 1]
        s_mean, s_var = weighted_moments(halved, static)
        seen = mask.mean(dim=0, keepdim=True)  # [1, R, S, 1]
        out = torch.cat([s_mean, s_var, masked_max(halved, mask), seen], dim=-1)  # [1, R, S, out_dim]
        return out[0], dynamic

    def static_weights(self, cos: Tensor, mask: Tensor) -> Tensor:
        """IBRNet's view weights [V, R, S, 1]: views looking along the query ray weigh more.

        The minimum over valid views is subtracted before normalising, so the worst valid view gets 0 weight
        (unless every valid view ties, which the small floor below resolves to uniform).
        """
        raw = torch.exp(self.sharpness.abs() * (cos - 1.0)) * mask
        floor = (raw + (1.0 - mask) * 2.0).amin(dim=0, keepdim=True)  # min over valid views (raw <= 1)
        shifted = (raw - floor).clamp(min=0.0) * mask + 1e-4 * mask
        return shifted / shifted.sum(dim=0, keepdim=True).clamp(min=1e-8)
