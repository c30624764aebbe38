"""The vanilla NeRF MLP with a HyperNet module inserted before each layer (or, for the ablation, concatenation).

Geometry: gamma(x) -> [conditioner -> original layer (Linear, LayerNorm, ReLU)] x nerf_layers -> density.
Layer i is conditioned on the aggregated features of scale min(i, 2): coarse (1/8) first, then 1/4, then 1/2
for the remaining layers (paper: H_2, H_1, H_0, H_0). Appearance: [geometry feature, gamma(d)] -> the appearance
module conditioned on the finest scale -> colour logits and a blend logit.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from insertnerf_cli.config import ModelConfig
from insertnerf_cli.model.hypernet import (
    AppearanceHyper,
    ConcatAppearance,
    ConcatLayer,
    GeometryHyperLayer,
    count_parameters,
    matched_hidden,
)


class PositionalEncoding(nn.Module):
    """gamma(x) = [x, sin(2^k x), cos(2^k x)] for k < freqs: [..., D] -> [..., D (1 + 2 freqs)]."""

    def __init__(self, in_dim: int, freqs: int) -> None:
        super().__init__()
        self.register_buffer("bands", 2.0 ** torch.arange(freqs, dtype=torch.float32), persistent=False)
        self.out_dim = in_dim * (1 + 2 * freqs)

    def forward(self, x: Tensor) -> Tensor:
        scaled = (x[..., None, :] * self.bands.to(x)[:, None]).flatten(-2)  # [..., freqs * D]
        return torch.cat([x, torch.sin(scaled), torch.cos(scaled)], dim=-1)


@dataclass(frozen=True)
class FieldOutput:
    """Raw field values at R x S samples: density [R, S] >= 0, colour [R, S, 3] in [0, 1], blend [R, S, 1]."""

    density: Tensor
    colour: Tensor
    blend: Tensor


def _geometry_conditioner(cfg: ModelConfig, cond_dim: int, samples: int, in_dim: int) -> nn.Module:
    hyper = GeometryHyperLayer(cond_dim, samples, in_dim, cfg.nerf_width, cfg.film_hidden, cfg.filter_nodes)
    if cfg.conditioning == "hyper":
        return hyper
    return ConcatLayer(cond_dim, in_dim, cfg.nerf_width,
                       matched_hidden(count_parameters(hyper), cond_dim, in_dim, cfg.nerf_width))


def _appearance_conditioner(cfg: ModelConfig, cond_dim: int, samples: int) -> nn.Module:
    width = cfg.appearance_width
    hyper = AppearanceHyper(cond_dim, samples, width, cfg.z_branches, cfg.filter_nodes)
    if cfg.conditioning == "hyper":
        return hyper
    fixed = count_parameters(ConcatAppearance(cond_dim, width, 1)) - count_parameters(ConcatLayer(cond_dim, width,
                                                                                                  width, 1))
    return ConcatAppearance(cond_dim, width, matched_hidden(count_parameters(hyper), cond_dim, width, width, fixed))


class NeRFHead(nn.Module):
    """The conditioned field of one pass.

    Args:
        cfg: model configuration (widths, depths, encodings, conditioning mode).
        cond_dims: widths of the aggregated descriptors per scale, coarse to fine.
        samples: S, samples per ray this head is used with (the HyperNet mixes along that axis).
        position_dims: the coordinates of a sample it reads: 3 (world x, y, z, times cfg.coord_scale) or 4 (the
            background's inverted-sphere coordinates, read as they are).
    """

    def __init__(self, cfg: ModelConfig, cond_dims: Sequence[int], samples: int, position_dims: int = 3) -> None:
        super().__init__()
        self.cfg = cfg
        self.coord_scale = cfg.coord_scale if position_dims == 3 else 1.0
        self.pos_enc = PositionalEncoding(position_dims, cfg.pe_freqs_pos)
        self.dir_enc = PositionalEncoding(3, cfg.pe_freqs_dir)
        self.layer_scale = [min(i, len(cond_dims) - 1) for i in range(cfg.nerf_layers)]
        in_dims = [self.pos_enc.out_dim] + [cfg.nerf_width] * (cfg.nerf_layers - 1)
        self.conditioners = nn.ModuleList(_geometry_conditioner(cfg, cond_dims[scale], samples, in_dim)
                                          for scale, in_dim in zip(self.layer_scale, in_dims))
        self.originals = nn.ModuleList(
            nn.Sequential(nn.Linear(cfg.nerf_width, cfg.nerf_width), nn.LayerNorm(cfg.nerf_width), nn.ReLU())
            for _ in range(cfg.nerf_layers))
        self.density = nn.Linear(cfg.nerf_width, 1)
        self.appearance_in = nn.Linear(cfg.nerf_width + self.dir_enc.out_dim, cfg.appearance_width)
        self.appearance = _appearance_conditioner(cfg, cond_dims[-1], samples)
        self.colour = nn.Linear(cfg.appearance_width, 3 + 1)  # rgb logits and the reference-blend logit

    def forward(self, points: Tensor, directions: Tensor, conds: Sequence[Tensor]) -> FieldOutput:
        """points [R, S, position_dims], directions [R, 3], conds per scale [R, S, D_l] -> FieldOutput."""
        h, density = self.geometry(points, conds)
        colour, blend = self.appearance_of(h, directions, conds[-1])
        return FieldOutput(density=density, colour=colour, blend=blend)

    def geometry(self, points: Tensor, conds: Sequence[Tensor]) -> tuple[Tensor, Tensor]:
        """The density MLP alone: (geometry feature [R, S, W], density [R, S])."""
        h = self.pos_enc(points * self.coord_scale)  # [R, S, P]
        for scale, conditioner, original in zip(self.layer_scale, self.conditioners, self.originals):
            h = original(conditioner(h, conds[scale]))  # [R, S, W]
        return h, self._activate(self.density(h)[..., 0])

    def appearance_of(self, h: Tensor, directions: Tensor, cond: Tensor) -> tuple[Tensor, Tensor]:
        """Colour [R, S, 3] and blend [R, S, 1] from the geometry feature, the view direction and the finest cond."""
        view = self.dir_enc(F.normalize(directions, dim=-1))[:, None].expand(-1, h.shape[1], -1)  # [R, S, E]
        q = F.relu(self.appearance_in(torch.cat([h, view], dim=-1)))  # [R, S, A]
        out = self.colour(self.appearance(q, cond))  # [R, S, 4]
        return torch.sigmoid(out[..., :3]), torch.sigmoid(out[..., 3:])

    def _activate(self, raw: Tensor) -> Tensor:
        raw = raw + self.cfg.density_bias
        if self.cfg.density_activation == "relu":
            return F.relu(raw)
        if self.cfg.density_activation == "exp":
            return torch.exp(raw.clamp(max=15.0))  # clamped: exp overflows long before it is useful
        return F.softplus(raw)
