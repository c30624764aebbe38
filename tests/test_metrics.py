"""PSNR and SSIM against analytic answers and a direct per-window evaluation of the SSIM definition."""
import math

import numpy as np
import pytest
import torch

from insertnerf_cli.metrics import (SSIM_K1, SSIM_K2, SSIM_SIGMA, SSIM_WINDOW, gaussian_window, psnr, psnr_from_mse,
                                    ssim)


def _image(seed: int, size: int = 24) -> np.ndarray:
    return np.random.default_rng(seed).random((size, size + 3, 3))


def test_psnr_identical_is_infinite():
    img = _image(0)
    assert psnr(img, img) == math.inf


def test_psnr_of_known_noise():
    # +-0.1 everywhere: MSE = 0.01, so PSNR = 10 log10(1 / 0.01) = 20 dB exactly.
    truth = np.full((8, 8, 3), 0.5)
    signs = np.where(np.indices((8, 8, 3)).sum(0) % 2 == 0, 1.0, -1.0)
    assert psnr(truth + 0.1 * signs, truth) == pytest.approx(20.0, abs=1e-9)
    # PSNR is relative to the peak: the same images on a 0-255 scale give the same figure.
    assert psnr(255 * (truth + 0.1 * signs), 255 * truth, max_value=255.0) == pytest.approx(20.0, abs=1e-9)


def test_psnr_from_a_mean_squared_error_is_the_same_figure_floored_for_logs():
    a, b = _image(1), _image(2)
    mse = float(((torch.from_numpy(a) - torch.from_numpy(b)) ** 2).mean())  # as psnr takes it
    assert psnr_from_mse(mse) == psnr(a, b)  # the same arithmetic as eval's scores
    assert psnr_from_mse(0.01) == pytest.approx(20.0, abs=1e-9)
    assert psnr_from_mse(0.0) == pytest.approx(100.0)  # an exact fit logs a number, not inf
    value = psnr_from_mse(torch.tensor([0.01, 0.0]))  # a tensor stays a tensor (training's loss terms)
    assert torch.is_tensor(value) and value.tolist() == pytest.approx([20.0, 100.0], abs=1e-4)


def test_psnr_accepts_tensors_and_rejects_shape_mismatch():
    a = torch.zeros(4, 4, 3)
    assert psnr(a + 0.01, a) == pytest.approx(40.0, abs=1e-6)
    with pytest.raises(ValueError):
        psnr(a, torch.zeros(4, 5, 3))


def test_ssim_identical_is_one():
    img = _image(1)
    assert ssim(img, img) == pytest.approx(1.0, abs=1e-12)


def test_ssim_of_constant_images_is_the_luminance_term():
    # Constant images have zero variance: SSIM reduces to (2ab + C1) / (a^2 + b^2 + C1).
    a, b = 0.2, 0.6
    c1 = SSIM_K1 ** 2
    expected = (2 * a * b + c1) / (a * a + b * b + c1)
    assert ssim(np.full((16, 16, 3), a), np.full((16, 16, 3), b)) == pytest.approx(expected, rel=1e-12)


def test_ssim_of_negated_contrast_is_negative():
    # b = 1 - a keeps means at 0.5 only on average; with a zero-mean pattern around 0.5 the structure term is -1.
    a = 0.5 + 0.2 * np.where(np.indices((20, 20)).sum(0) % 2 == 0, 1.0, -1.0)[..., None].repeat(3, -1)
    value = ssim(a, 1.0 - a)
    assert -1.0 <= value < 0.0


def _ssim_by_definition(a: np.ndarray, b: np.ndarray) -> float:
    """Weighted statistics of every fully-inside 11x11 window, straight from Wang et al.'s formula."""
    g = gaussian_window(SSIM_WINDOW, SSIM_SIGMA).numpy()
    w = np.outer(g, g)
    c1, c2 = SSIM_K1 ** 2, SSIM_K2 ** 2
    k = SSIM_WINDOW
    values = []
    for ch in range(a.shape[2]):
        for i in range(a.shape[0] - k + 1):
            for j in range(a.shape[1] - k + 1):
                pa, pb = a[i:i + k, j:j + k, ch], b[i:i + k, j:j + k, ch]
                ma, mb = (w * pa).sum(), (w * pb).sum()
                va, vb = (w * (pa - ma) ** 2).sum(), (w * (pb - mb) ** 2).sum()
                cov = (w * (pa - ma) * (pb - mb)).sum()
                values.append((2 * ma * mb + c1) * (2 * cov + c2) / ((ma ** 2 + mb ** 2 + c1) * (va + vb + c2)))
    return float(np.mean(values))


def test_ssim_matches_the_definition_window_by_window():
    a = _image(2, 14)
    b = np.clip(a + 0.1 * np.random.default_rng(3).standard_normal(a.shape), 0, 1)
    assert ssim(a, b) == pytest.approx(_ssim_by_definition(a, b), rel=1e-10)


def test_ssim_is_symmetric_and_drops_with_noise():
    a = _image(4)
    rng = np.random.default_rng(5)
    small = np.clip(a + 0.02 * rng.standard_normal(a.shape), 0, 1)
    large = np.clip(a + 0.2 * rng.standard_normal(a.shape), 0, 1)
    assert ssim(a, small) == pytest.approx(ssim(small, a), rel=1e-12)
    assert 1.0 > ssim(a, small) > ssim(a, large)


def test_gaussian_window_is_normalised_and_symmetric():
    g = gaussian_window(SSIM_WINDOW, SSIM_SIGMA)
    assert float(g.sum()) == pytest.approx(1.0)
    assert torch.allclose(g, g.flip(0))
    assert int(g.argmax()) == SSIM_WINDOW // 2


def test_ssim_rejects_images_smaller_than_the_window():
    with pytest.raises(ValueError):
        ssim(np.zeros((5, 5, 3)), np.zeros((5, 5, 3)))
