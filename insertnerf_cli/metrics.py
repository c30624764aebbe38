"""Image quality metrics: PSNR (of images, or of a mean squared error) and SSIM (Wang et al. 2004) on RGB images
in [0, 1]. The one place PSNR is computed: eval's scores, training's and fine-tuning's logs and the benches.

SSIM follows the standard definition: an 11x11 Gaussian window with sigma 1.5, K1 = 0.01, K2 = 0.03, local
statistics over the window (population variances), computed only where the window fits inside the image
("valid"), averaged over pixels and channels -- the same choices as the reference MATLAB code and multinerf.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import check_shape

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
MSE_FLOOR = 1e-10  # the smallest mean squared error psnr_from_mse reads by default (100 dB)


def _as_tensor(image: Tensor | np.ndarray) -> Tensor:
    return image.double() if isinstance(image, Tensor) else torch.from_numpy(np.asarray(image, dtype=np.float64))


def psnr(image: Tensor | np.ndarray, truth: Tensor | np.ndarray, max_value: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB of ``image`` against ``truth`` (same shape); inf when they are identical."""
    a, b = _as_tensor(image), _as_tensor(truth)
    if a.shape != b.shape:
        raise ValueError(f"image {list(a.shape)} and truth {list(b.shape)} differ in shape")
    mse = float(((a - b) ** 2).mean())
    return math.inf if mse == 0.0 else psnr_from_mse(mse, max_value, floor=0.0)


def psnr_from_mse(mse: float | Tensor, max_value: float = 1.0, floor: float = MSE_FLOOR) -> float | Tensor:
    """:func:`psnr` in dB from a mean squared error already taken (training's logs and losses): a float for a
    number, a tensor for a tensor (no host sync, safe under autograd). The error is floored at ``floor`` so that
    an exact fit logs a finite PSNR (100 dB for values in [0, 1]); :func:`psnr` passes 0 and says inf itself."""
    if isinstance(mse, Tensor):
        return 10.0 * torch.log10(max_value ** 2 / mse.clamp(min=floor))
    mse = max(float(mse), floor)
    return -math.inf if mse == math.inf else 10.0 * math.log10(max_value ** 2 / mse)


def gaussian_window(size: int, sigma: float, dtype: torch.dtype = torch.float64) -> Tensor:
    """Normalised 1-D Gaussian weights [size] centred on the middle tap."""
    x = torch.arange(size, dtype=dtype) - (size - 1) / 2
    w = torch.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def _filter(x: Tensor, window: Tensor) -> Tensor:
    """Separable 'valid' Gaussian filter of x [C, H, W] -> [C, H-k+1, W-k+1]."""
    c, k = x.shape[0], window.shape[0]
    rows = window.view(1, 1, k, 1).expand(c, 1, k, 1)
    cols = window.view(1, 1, 1, k).expand(c, 1, 1, k)
    out = torch.nn.functional.conv2d(x[None], rows, groups=c)
    return torch.nn.functional.conv2d(out, cols, groups=c)[0]


def ssim_map(image: Tensor | np.ndarray, truth: Tensor | np.ndarray, max_value: float = 1.0,
             window_size: int = SSIM_WINDOW) -> Tensor:
    """Per-pixel SSIM [C, H-k+1, W-k+1] of images [H, W, C] (or [H, W]); k = window_size (odd)."""
    a, b = _as_tensor(image), _as_tensor(truth)
    if a.dim() == 2:
        a, b = a[..., None], b[..., None]
    check_shape("image", a, (None, None, None))
    check_shape("truth", b, tuple(a.shape))
    if min(a.shape[:2]) < window_size:
        raise ValueError(f"SSIM needs images of at least {window_size}x{window_size} px, got {list(a.shape[:2])}")
    window = gaussian_window(window_size, SSIM_SIGMA)
    a, b = a.permute(2, 0, 1), b.permute(2, 0, 1)  # [C, H, W]
    mu_a, mu_b = _filter(a, window), _filter(b, window)
    var_a = _filter(a * a, window) - mu_a ** 2
    var_b = _filter(b * b, window) - mu_b ** 2
    cov = _filter(a * b, window) - mu_a * mu_b
    c1, c2 = (SSIM_K1 * max_value) ** 2, (SSIM_K2 * max_value) ** 2
    return ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2))


def ssim(image: Tensor | np.ndarray, truth: Tensor | np.ndarray, max_value: float = 1.0) -> float:
    """Mean structural similarity of images [H, W, C] in [0, max_value]; 1 when identical."""
    return float(ssim_map(image, truth, max_value).mean())
