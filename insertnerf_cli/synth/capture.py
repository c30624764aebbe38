"""From linear radiance to an 8-bit photo: exposure, optional capture effects (exposure and white-balance
jitter between views, sensor noise, JPEG compression), sRGB encoding.

Each effect is off by default and switched on through :class:`CaptureOptions`; the strength of each is drawn
per scene (``CaptureSettings``) and the per-view randomness comes from the view's own generator, so images
stay reproducible.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

from .textures import linear_to_srgb

# Luminance weights of linear sRGB (Rec. 709).
_LUMA = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class CaptureOptions:
    """Which capture effects a dataset uses (recorded in the manifest)."""

    noise: bool = False
    jitter: bool = False
    jpeg: bool = False


@dataclass(frozen=True)
class CaptureSettings:
    """Per-scene strengths, drawn once: noise (shot ``gain`` and ``read`` std in linear units), jitter
    (``exposure_std`` in stops, ``white_balance_std`` per channel), ``jpeg_quality`` (0 = off)."""

    gain: float = 0.0
    read: float = 0.0
    exposure_std: float = 0.0
    white_balance_std: float = 0.0
    jpeg_quality: int = 0

    def to_json(self) -> dict:
        return asdict(self)


def draw_settings(rng: np.random.Generator, options: CaptureOptions) -> CaptureSettings:
    """Strengths for one scene: from clean phone daylight to a noisy, heavily compressed capture."""
    return CaptureSettings(
        gain=float(np.exp(rng.uniform(np.log(2e-4), np.log(5e-3)))) if options.noise else 0.0,
        read=float(np.exp(rng.uniform(np.log(5e-4), np.log(6e-3)))) if options.noise else 0.0,
        exposure_std=float(rng.uniform(0.03, 0.2)) if options.jitter else 0.0,
        white_balance_std=float(rng.uniform(0.01, 0.04)) if options.jitter else 0.0,
        jpeg_quality=int(rng.integers(60, 96)) if options.jpeg else 0)


def develop(radiance: np.ndarray, settings: CaptureSettings, rng: np.random.Generator) -> np.ndarray:
    """Linear radiance [H, W, 3] (already exposed) -> uint8 sRGB [H, W, 3] with this scene's capture effects.

    ``rng`` is the view's own generator; effects that are off draw nothing from it.
    """
    image = radiance
    if settings.exposure_std > 0 or settings.white_balance_std > 0:
        gains = np.exp(rng.normal(0, settings.exposure_std) * np.log(2)) \
            * np.exp(rng.normal(0, settings.white_balance_std, 3))
        image = image * gains
    if settings.gain > 0 or settings.read > 0:
        # Photon shot noise grows with the signal, read noise does not.
        sigma = np.sqrt(settings.gain * np.clip(image, 0, None) + settings.read ** 2)
        image = image + sigma * rng.standard_normal(image.shape)
    out = np.rint(linear_to_srgb(image) * 255).astype(np.uint8)
    if settings.jpeg_quality:
        ok, data = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, settings.jpeg_quality])
        out = cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1]
    return np.ascontiguousarray(out)


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Linear luminance [...] of linear RGB [..., 3]."""
    return rgb @ _LUMA
