"""U-Net feature extractor over the reference images, trained from scratch, with three output scales.

Down path: stride-2 stages to 1/2, 1/4, 1/8, 1/16 of the image. Up path: back to 1/8, 1/4, 1/2 with skip
connections; a 1x1 head per scale gives the features F_2 (1/8), F_1 (1/4), F_0 (1/2). A small decoder, used only
by the backbone reconstruction loss, rebuilds the image from the finest features (docs/method.md, Encoder).
"""
from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

# Three outputs at 1/8, 1/4, 1/2 need a 1/16 bottleneck: four stride-2 stages.
LEVELS = 4
STRIDE = 2 ** LEVELS


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride=stride, padding=1), nn.ReLU(inplace=True))


class UNetEncoder(nn.Module):
    """Images [V, 3, Hp, Wp] (Hp, Wp multiples of STRIDE) -> features at 1/8, 1/4, 1/2 (coarse to fine).

    Args:
        widths: channels of the down stages at 1/2, 1/4, 1/8, 1/16 (LEVELS values).
        feature_dims: output channels at 1/8, 1/4, 1/2.
        decoder_width: hidden channels of the reconstruction decoder.
    """

    def __init__(self, widths: Sequence[int], feature_dims: Sequence[int], decoder_width: int) -> None:
        super().__init__()
        if len(widths) != LEVELS or len(feature_dims) != LEVELS - 1:
            raise ValueError(f"need {LEVELS} widths and {LEVELS - 1} feature dims")
        ins = [3, *widths[:-1]]
        self.down = nn.ModuleList(nn.Sequential(_conv(cin, cout, stride=2), _conv(cout, cout))
                                  for cin, cout in zip(ins, widths))
        # Up stage k goes from level LEVELS-1-k to LEVELS-2-k, concatenating that level's skip.
        self.up = nn.ModuleList()
        below = widths[-1]
        for level in reversed(range(LEVELS - 1)):
            self.up.append(_conv(below + widths[level], widths[level]))
            below = widths[level]
        # Non-negative features (ReLU heads): with zeros for views that miss a sample, a plain max over views
        # is the max over the valid ones (see aggregate.py).
        self.heads = nn.ModuleList(nn.Sequential(nn.Conv2d(widths[level], dim, 1), nn.ReLU())
                                   for level, dim in zip(reversed(range(LEVELS - 1)), feature_dims))
        self.decoder = nn.Sequential(nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False),
                                     _conv(feature_dims[-1], decoder_width), nn.Conv2d(decoder_width, 3, 3, padding=1),
                                     nn.Sigmoid())

    def forward(self, images: Tensor) -> tuple[Tensor, ...]:
        """images [V, 3, Hp, Wp] in [0, 1] -> (F_2 [V, C0, Hp/8, Wp/8], F_1 [.., Hp/4, ..], F_0 [.., Hp/2, ..])."""
        x = images * 2.0 - 1.0
        skips = []
        for stage in self.down:
            x = stage(x)
            skips.append(x)
        outputs = []
        for stage, head, skip in zip(self.up, self.heads, reversed(skips[:-1])):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = stage(torch.cat([x, skip], dim=1))
            outputs.append(head(x))
        return tuple(outputs)

    def reconstruct(self, finest: Tensor) -> Tensor:
        """Finest features [V, C, Hp/2, Wp/2] -> rebuilt images [V, 3, Hp, Wp] (for the backbone loss only)."""
        return self.decoder(finest)


def pad_to_stride(images: Tensor) -> Tensor:
    """Zero-pad [V, C, H, W] on the right and bottom to multiples of STRIDE (the pixel grid keeps its origin)."""
    height, width = images.shape[-2:]
    pad_h, pad_w = -height % STRIDE, -width % STRIDE
    return F.pad(images, (0, pad_w, 0, pad_h)) if pad_h or pad_w else images
