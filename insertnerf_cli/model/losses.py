"""The training objective (paper section 3.4; docs/method.md, Training):
colour MSE on both passes + w_b * backbone reconstruction MSE + w_dy * dynamic-weight colour MSE, and the geometry
terms (geometry_losses.py): w_depth * depth + w_dist * distortion, each the mean of both passes."""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from insertnerf_cli.cameras.camera import check_shape
from insertnerf_cli.cameras.rays import Rays
from insertnerf_cli.config import ModelConfig
from insertnerf_cli.metrics import psnr_from_mse
from insertnerf_cli.model.geometry_losses import NO_SURFACE, depth_loss, distortion_loss
from insertnerf_cli.model.types import EncodedViews, LossTerms, RenderOutput


def compute_losses(cfg: ModelConfig, output: RenderOutput, target_rgb: Tensor, encoded: EncodedViews,
                   rays: Rays | None = None, target_depth: Tensor | None = None) -> LossTerms:
    """LossTerms for R rays with ground-truth colours target_rgb [R, 3] (composited on the same background).

    The backbone term needs ``encoded.reconstruction`` (present when encoded in training mode); without it the
    term is 0. The dynamic term composites the dynamic-weight colour blend with the passes' detached weights, so it
    trains the dynamic weights to pick the views that see the surface without moving the geometry.
    ``target_depth`` [R] (NaN = unknown, 0 = no surface) feeds the depth term; ``rays`` (their bounds) the
    distortion term. Either missing makes its term 0.
    """
    check_shape("target_rgb", target_rgb, (output.fine.rgb.shape[0], 3))
    mse_coarse = F.mse_loss(output.coarse.rgb, target_rgb)
    mse_fine = F.mse_loss(output.fine.rgb, target_rgb)
    dynamic = 0.5 * (F.mse_loss(output.dynamic_coarse, target_rgb) + F.mse_loss(output.dynamic_fine, target_rgb))
    if encoded.reconstruction is not None:
        backbone = F.mse_loss(encoded.reconstruction, encoded.source_images())
    else:
        backbone = torch.zeros((), dtype=target_rgb.dtype, device=target_rgb.device)
    zero = torch.zeros((), dtype=target_rgb.dtype, device=target_rgb.device)
    passes = ((output.coarse.weights, output.coarse_samples), (output.fine.weights, output.fine_samples))
    depth = zero
    if target_depth is not None and cfg.loss_depth_weight > 0:
        if not cfg.infinity_sample:  # a fixed background cannot show a plain backdrop of another colour, so a
            # ray without a surface may need a surface-like stand-in: its depth says nothing then
            target_depth = torch.where(target_depth > NO_SURFACE, target_depth, torch.nan)
        depth = sum(depth_loss(w, s.edges, target_depth) for w, s in passes) / len(passes)
    distortion = zero
    if rays is not None and cfg.loss_distortion_weight > 0:
        distortion = sum(distortion_loss(w, s.edges, rays.near, rays.far, cfg.sample_in_disparity)
                         for w, s in passes) / len(passes)
    total = (mse_coarse + mse_fine + cfg.loss_backbone_weight * backbone + cfg.loss_dynamic_weight * dynamic
             + cfg.loss_depth_weight * depth + cfg.loss_distortion_weight * distortion)
    return LossTerms(total=total, mse_coarse=mse_coarse.detach(), mse_fine=mse_fine.detach(),
                     backbone=backbone.detach(), dynamic=dynamic.detach(),
                     psnr_fine=psnr_from_mse(mse_fine.detach()), depth=depth.detach(), distortion=distortion.detach())
