"""The sampling-aware filter: a graph convolution over the S samples of each ray (paper Eq. 8).

H = F + ReLU(((I - A) F) W): A mixes the samples of a ray (a learned adjacency over its S samples), W the features,
and the residual keeps each sample's own descriptor. As in GloRe, the graph lives on a few latent nodes: A = U V
with V [N, S] projecting the samples onto N nodes and U [S, N] spreading them back. With N << S this costs 2 N D
per sample instead of S D for a dense [S, S] adjacency (4x less at S = 64, N = 8), for the same kind of mixing.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class SamplingFilter(nn.Module):
    """[R, S, D] -> [R, S, D] mixing along the sample axis (S fixed) and the feature axis.

    Args:
        dim: D, feature width.
        samples: S, samples per ray.
        nodes: N, rank of the adjacency (latent graph nodes).
    """

    def __init__(self, dim: int, samples: int, nodes: int) -> None:
        super().__init__()
        self.to_nodes = nn.Parameter(torch.randn(nodes, samples) / samples ** 0.5)  # V [N, S]
        # U starts at zero: the filter starts as a plain per-sample layer and learns how much to mix.
        self.from_nodes = nn.Parameter(torch.zeros(samples, nodes))  # U [S, N]
        self.features = nn.Linear(dim, dim)

    def forward(self, x: Tensor) -> Tensor:
        rays = x.shape[0]
        nodes = torch.bmm(self.to_nodes.expand(rays, -1, -1), x)  # [R, N, D]
        mixed = torch.baddbmm(x, self.from_nodes.expand(rays, -1, -1), nodes, alpha=-1.0)  # (I - U V) F  [R, S, D]
        return x + F.relu(self.features(mixed))
