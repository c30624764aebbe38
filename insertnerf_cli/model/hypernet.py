"""HyperNet modules: layers whose weights are generated per ray from the aggregated reference-view features.

Geometry module (before each density-MLP layer): sampling-aware filter -> a dynamic linear layer whose matrix is
generated per ray (feature-axis linear, then a linear along the sample axis, as in the released code) and whose
bias is generated per sample -> DFiLM, y = (1 + freq) * (W x + b) + shift, with freq/shift per sample.
Appearance module: Z progressive hyper branches, branch z conditioned on a refinement of branch z-1's condition.
The ``Concat*`` twins are the ablation: the same slot filled by plain concatenation of the features.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from insertnerf_cli.model.filter import SamplingFilter


class RayWeights(nn.Module):
    """Per-ray matrices [R, I, O] from per-sample conditions [R, S, D] (the released code's "NR" block)."""

    def __init__(self, cond_dim: int, samples: int, in_dim: int, out_dim: int) -> None:
        super().__init__()
        self.features = nn.Linear(cond_dim, in_dim)
        self.mix = nn.Linear(samples, out_dim)
        # Generated weights act like a layer with fan-in I: scale them so outputs start at unit variance.
        self.gain = in_dim ** -0.5

    def forward(self, cond: Tensor) -> Tensor:
        rows = F.relu(self.features(cond))  # [R, S, I]
        # W[r] = gain (rows[r]^T mix^T + b): [I, S] @ [S, O] per ray, bias and gain folded into one baddbmm
        # (einsum copies the operands here)
        return torch.baddbmm(self.mix.bias, rows.transpose(1, 2), self.mix.weight.T.expand(rows.shape[0], -1, -1),
                             beta=self.gain, alpha=self.gain)  # [R, I, O]


class GeometryHyperLayer(nn.Module):
    """x [R, S, I], cond [R, S, D] -> [R, S, O] through a generated linear layer, a generated bias and DFiLM."""

    def __init__(self, cond_dim: int, samples: int, in_dim: int, out_dim: int, film_hidden: int,
                 nodes: int) -> None:
        super().__init__()
        self.filter = SamplingFilter(cond_dim, samples, nodes)
        self.weights = RayWeights(cond_dim, samples, in_dim, out_dim)
        # One per-sample MLP generates the bias and the DFiLM frequency and shift (3 O outputs): one call, not two.
        self.film = nn.Sequential(nn.Linear(cond_dim, film_hidden), nn.LeakyReLU(0.2),
                                  nn.Linear(film_hidden, 3 * out_dim))

    def forward(self, x: Tensor, cond: Tensor) -> Tensor:
        h = self.filter(cond)  # [R, S, D]
        bias, freq, shift = self.film(h).chunk(3, dim=-1)  # [R, S, O] each
        y = torch.baddbmm(bias, x, self.weights(h))  # [R, S, O]
        return torch.addcmul(y + shift, freq, y)  # (1 + freq) y + shift, in two passes instead of three


class AppearanceHyper(nn.Module):
    """Z progressive hyper branches: q [R, S, A] -> [R, S, A] conditioned on cond [R, S, D]."""

    def __init__(self, cond_dim: int, samples: int, width: int, branches: int, nodes: int) -> None:
        super().__init__()
        self.filter = SamplingFilter(cond_dim, samples, nodes)
        self.branches = nn.ModuleList(RayWeights(cond_dim, samples, width, width) for _ in range(branches))
        self.progress = nn.ModuleList(nn.Linear(cond_dim, cond_dim) for _ in range(branches - 1))
        self.out = nn.Linear(width, width)
        self.norm = nn.LayerNorm(width)

    def forward(self, q: Tensor, cond: Tensor) -> Tensor:
        h = self.filter(cond)
        total = torch.zeros_like(q)
        for z, branch in enumerate(self.branches):
            total = total + torch.bmm(q, branch(h))  # [R, S, A]
            if z < len(self.progress):
                h = h + F.relu(self.progress[z](h))  # the next branch builds on this one's condition
        return self.norm(F.relu(self.out(total)) + q)


class ConcatLayer(nn.Module):
    """Ablation of GeometryHyperLayer: Linear([x, MLP(cond)]) with the hidden width chosen to match its size."""

    def __init__(self, cond_dim: int, in_dim: int, out_dim: int, hidden: int) -> None:
        super().__init__()
        self.cond = nn.Linear(cond_dim, hidden)
        self.linear = nn.Linear(in_dim + hidden, out_dim)

    def forward(self, x: Tensor, cond: Tensor) -> Tensor:
        return self.linear(torch.cat([x, F.relu(self.cond(cond))], dim=-1))


class ConcatAppearance(nn.Module):
    """Ablation of AppearanceHyper: q + MLP([q, MLP(cond)]), residual and LayerNorm as in the hyper version."""

    def __init__(self, cond_dim: int, width: int, hidden: int) -> None:
        super().__init__()
        self.layer = ConcatLayer(cond_dim, width, width, hidden)
        self.out = nn.Linear(width, width)
        self.norm = nn.LayerNorm(width)

    def forward(self, q: Tensor, cond: Tensor) -> Tensor:
        return self.norm(F.relu(self.out(F.relu(self.layer(q, cond)))) + q)


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def matched_hidden(target: int, cond_dim: int, in_dim: int, out_dim: int, extra: int = 0) -> int:
    """Hidden width h making a ConcatLayer (plus ``extra`` fixed parameters) hold about ``target`` parameters.

    ConcatLayer holds (D + 1) h + (I + h + 1) O parameters, linear in h.
    """
    fixed = (in_dim + 1) * out_dim + extra
    return max(1, round((target - fixed) / (cond_dim + 1 + out_dim)))
