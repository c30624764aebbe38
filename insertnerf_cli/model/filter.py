"""The sampling-aware filter: a graph convolution over the S samples of each ray (paper Eq. 8).

The S samples of a ray are the nodes of a fully connected graph with a learned adjacency A [S, S];
H = F + ReLU(((I - A) F) W), as in GloRe: a linear map along the sample axis, one along the feature axis, and a
residual. It lets each sample's conditioning see its neighbours along the ray, e.g. where the surface is.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class SamplingFilter(nn.Module):
    """[R, S, D] -> [R, S, D] mixing along the sample axis (S fixed) and the feature axis."""

    def __init__(self, dim: int, samples: int) -> None:
        super().__init__()
        # A starts at zero so the filter starts as a plain per-sample layer and learns how much to mix.
        self.adjacency = nn.Parameter(torch.zeros(samples, samples))
        self.features = nn.Linear(dim, dim)

    def forward(self, x: Tensor) -> Tensor:
        mixed = x - torch.einsum("ts,rsd->rtd", self.adjacency, x)  # (I - A) F; t, s: samples, d: features
        return x + F.relu(self.features(mixed))
