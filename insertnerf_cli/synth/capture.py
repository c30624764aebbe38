"""From linear radiance to an 8-bit photo: exposure, optional capture effects, sRGB encoding.

Effects, each off by default and switched on through :class:`CaptureOptions`: exposure and white-balance
jitter between views (--jitter), sensor noise (--noise), JPEG compression (--jpeg), and --photo: noise and
JPEG plus exposure offsets up to +-0.5 stop and white-balance shifts per view, slight defocus or motion blur,
and lens vignetting. The strength of each is drawn per scene (:class:`CaptureSettings`) and the per-view
values from the view's own generator, so images stay reproducible; each view's values are recorded
(:class:`ViewCapture`) in scene.json.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

from insertnerf_cli.synth.textures import linear_to_srgb

# Luminance weights of linear sRGB (Rec. 709).
_LUMA = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class CaptureOptions:
    """Which capture effects a dataset uses (recorded in the manifest); ``photo`` implies noise and JPEG."""

    noise: bool = False
    jitter: bool = False
    jpeg: bool = False
    photo: bool = False


@dataclass(frozen=True)
class CaptureSettings:
    """Per-scene strengths, drawn once: noise (shot ``gain`` and ``read`` std in linear units), jitter
    (``exposure_std`` in stops, ``white_balance_std`` per channel), ``jpeg_quality`` (0 = off), and --photo's
    ``exposure_range`` (per-view offsets uniform in +-range stops), ``white_balance_range`` (per-channel log
    gains uniform in +-range), ``blur`` (largest blur of a view, pixels) and ``vignetting`` (fraction of the
    light lost in the image corners: a property of the lens, the same in every view)."""

    gain: float = 0.0
    read: float = 0.0
    exposure_std: float = 0.0
    white_balance_std: float = 0.0
    jpeg_quality: int = 0
    exposure_range: float = 0.0
    white_balance_range: float = 0.0
    blur: float = 0.0
    vignetting: float = 0.0

    def to_json(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ViewCapture:
    """What one view went through: ``exposure_stops`` (0 = the scene's exposure), ``white_balance`` gains
    (R, G, B), Gaussian ``defocus_sigma`` and ``motion_length`` (pixels) at ``motion_angle`` (degrees),
    ``vignetting`` (corner light loss), noise ``gain``/``read`` and ``jpeg_quality`` (0 = none)."""

    exposure_stops: float = 0.0
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    defocus_sigma: float = 0.0
    motion_length: float = 0.0
    motion_angle: float = 0.0
    vignetting: float = 0.0
    gain: float = 0.0
    read: float = 0.0
    jpeg_quality: int = 0

    def to_json(self) -> dict:
        return {**asdict(self), "white_balance": list(self.white_balance)}


def draw_settings(rng: np.random.Generator, options: CaptureOptions) -> CaptureSettings:
    """Strengths for one scene: from clean phone daylight to a noisy, heavily compressed capture."""
    noise, jpeg, photo = options.noise or options.photo, options.jpeg or options.photo, options.photo
    return CaptureSettings(
        gain=float(np.exp(rng.uniform(np.log(2e-4), np.log(5e-3)))) if noise else 0.0,
        read=float(np.exp(rng.uniform(np.log(5e-4), np.log(6e-3)))) if noise else 0.0,
        exposure_std=float(rng.uniform(0.03, 0.2)) if options.jitter else 0.0,
        white_balance_std=float(rng.uniform(0.01, 0.04)) if options.jitter else 0.0,
        jpeg_quality=int(rng.integers(60, 96)) if jpeg else 0,
        exposure_range=float(rng.uniform(0.0, 0.5)) if photo else 0.0,
        white_balance_range=float(rng.uniform(0.0, 0.05)) if photo else 0.0,
        blur=float(rng.uniform(0.0, 1.2)) if photo else 0.0,
        vignetting=float(rng.uniform(0.0, 0.4)) if photo else 0.0)


def draw_view(settings: CaptureSettings, rng: np.random.Generator) -> ViewCapture:
    """The values of one view from its own generator; effects that are off draw nothing."""
    stops, log_wb = 0.0, np.zeros(3)
    if settings.exposure_std > 0 or settings.white_balance_std > 0:
        stops += rng.normal(0, settings.exposure_std)
        log_wb += rng.normal(0, settings.white_balance_std, 3)
    defocus = motion = angle = 0.0
    if settings.exposure_range > 0 or settings.white_balance_range > 0 or settings.blur > 0:
        stops += rng.uniform(-settings.exposure_range, settings.exposure_range)
        log_wb += rng.uniform(-settings.white_balance_range, settings.white_balance_range, 3)
        amount, moved, angle = settings.blur * rng.random(), rng.random() < 0.3, float(rng.uniform(0, 180))
        defocus, motion = (0.0, 2.5 * amount) if moved else (amount, 0.0)
    return ViewCapture(float(stops), tuple(float(g) for g in np.exp(log_wb)), float(defocus), float(motion),
                       angle if motion > 0 else 0.0, settings.vignetting, settings.gain, settings.read,
                       settings.jpeg_quality)


def develop(radiance: np.ndarray, settings: CaptureSettings, rng: np.random.Generator
            ) -> tuple[np.ndarray, ViewCapture]:
    """Linear radiance [H, W, 3] (already exposed) -> uint8 sRGB [H, W, 3] with this scene's capture effects,
    applied in the order light meets them: blur (lens, motion), vignetting, exposure and white balance,
    sensor noise, then sRGB encoding and JPEG. ``rng`` is the view's own generator."""
    view = draw_view(settings, rng)
    image = _blurred(radiance, view)
    if view.vignetting > 0:
        image = image * vignette(image.shape[0], image.shape[1], view.vignetting)[..., None]
    gains = 2.0 ** view.exposure_stops * np.asarray(view.white_balance)
    if np.any(gains != 1.0):
        image = image * gains
    if settings.gain > 0 or settings.read > 0:
        # Photon shot noise grows with the signal, read noise does not.
        sigma = np.sqrt(settings.gain * np.clip(image, 0, None) + settings.read ** 2)
        image = image + sigma * rng.standard_normal(image.shape)
    out = np.rint(linear_to_srgb(image) * 255).astype(np.uint8)
    if settings.jpeg_quality:
        ok, data = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, settings.jpeg_quality])
        out = cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1]
    return np.ascontiguousarray(out), view


def vignette(height: int, width: int, strength: float) -> np.ndarray:
    """[H, W] gain 1 - strength * (r / r_corner)^2: 1 at the centre, 1 - strength in the corners."""
    y = (np.arange(height) + 0.5 - height / 2)[:, None]
    x = (np.arange(width) + 0.5 - width / 2)[None, :]
    return 1.0 - strength * (x ** 2 + y ** 2) / ((height / 2) ** 2 + (width / 2) ** 2)


def _blurred(image: np.ndarray, view: ViewCapture) -> np.ndarray:
    """Radiance [H, W, 3] through the view's defocus (Gaussian) or motion (a line of ``motion_length``)."""
    if view.defocus_sigma > 0.05:
        return cv2.GaussianBlur(image, (0, 0), view.defocus_sigma, borderType=cv2.BORDER_REFLECT)
    if view.motion_length > 0.1:
        size = 2 * int(np.ceil(view.motion_length / 2)) + 1
        kernel = np.zeros((size * 8, size * 8), dtype=np.float32)  # drawn 8x larger, then shrunk: sub-pixel
        c, half = size * 4, view.motion_length * 4
        dx, dy = half * np.cos(np.radians(view.motion_angle)), half * np.sin(np.radians(view.motion_angle))
        cv2.line(kernel, (int(round(c - dx)), int(round(c - dy))), (int(round(c + dx)), int(round(c + dy))), 1.0, 8)
        kernel = cv2.resize(kernel, (size, size), interpolation=cv2.INTER_AREA)
        return cv2.filter2D(image, -1, kernel / kernel.sum(), borderType=cv2.BORDER_REFLECT)
    return image


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Linear luminance [...] of linear RGB [..., 3]."""
    return rgb @ _LUMA
