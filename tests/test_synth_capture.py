"""insertnerf synth capture effects (--noise, --jitter, --jpeg, --photo): each present when switched on,
absent when off, with the values of every view recorded."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from insertnerf_cli.cli.main import cli
from insertnerf_cli.synth.capture import CaptureOptions, CaptureSettings, develop, draw_settings, vignette
from insertnerf_cli.synth.textures import linear_to_srgb, srgb_to_linear

GREY = 0.18


def _flat(height: int = 40, width: int = 60) -> np.ndarray:
    return np.full((height, width, 3), GREY)


def _linear(image: np.ndarray) -> np.ndarray:
    return srgb_to_linear(image.astype(np.float64) / 255)


def test_no_effect_is_applied_or_drawn_when_all_are_off():
    rng = np.random.default_rng(0)
    out, view = develop(_flat(), CaptureSettings(), rng)
    assert (out == np.rint(linear_to_srgb(np.float64(GREY)) * 255)).all()
    assert view.exposure_stops == 0 and view.white_balance == (1.0, 1.0, 1.0) and view.vignetting == 0
    assert view.defocus_sigma == 0 and view.motion_length == 0 and view.jpeg_quality == 0
    assert rng.random() == np.random.default_rng(0).random()  # nothing was drawn from the view's generator


def test_photo_switches_on_every_effect_and_the_others_stay_off():
    settings = draw_settings(np.random.default_rng(1), CaptureOptions(photo=True))
    assert settings.gain > 0 and settings.read > 0 and settings.jpeg_quality > 0
    assert 0 < settings.exposure_range <= 0.5 and settings.white_balance_range > 0
    assert settings.blur > 0 and settings.vignetting > 0
    plain = draw_settings(np.random.default_rng(1), CaptureOptions())
    assert plain == CaptureSettings()


def test_vignetting_darkens_the_corners_by_its_strength_and_spares_the_centre():
    gain = vignette(40, 60, 0.3)
    assert gain[0, 0] == pytest.approx(0.7, abs=0.02) and gain[20, 30] == pytest.approx(1.0, abs=1e-3)
    out, view = develop(_flat(), CaptureSettings(vignetting=0.3), np.random.default_rng(0))
    linear = _linear(out)[..., 1]
    assert view.vignetting == 0.3
    assert linear[0, 0] / linear[20, 30] == pytest.approx(0.7, abs=0.03)


def test_exposure_and_white_balance_scale_the_light_by_the_recorded_gains():
    settings = CaptureSettings(exposure_range=0.5, white_balance_range=0.05)
    stops = []
    for seed in range(20):
        out, view = develop(_flat(), settings, np.random.default_rng(seed))
        expected = GREY * 2 ** view.exposure_stops * np.array(view.white_balance)
        np.testing.assert_allclose(_linear(out)[0, 0], expected, rtol=0.02)
        stops.append(view.exposure_stops)
    assert max(np.abs(stops)) <= 0.5 and np.ptp(stops) > 0.3  # spread over +-0.5 stop


def test_blur_spreads_a_sharp_edge_only_when_switched_on():
    edge = np.zeros((32, 32, 3))
    edge[:, 16:] = 0.8
    sharp, _ = develop(edge, CaptureSettings(), np.random.default_rng(0))
    assert len(np.unique(sharp[..., 0])) == 2
    blurred = [develop(edge, CaptureSettings(blur=1.2), np.random.default_rng(seed)) for seed in range(8)]
    views = [view for _, view in blurred]
    assert all(v.defocus_sigma <= 1.2 and v.motion_length <= 3.0 for v in views)
    spread = [len(np.unique(out[16, :, 0])) > 2 for out, v in blurred if max(v.defocus_sigma, v.motion_length) > 0.3]
    assert spread and all(spread)


def test_noise_and_jpeg_change_pixels_only_when_switched_on():
    texture = np.random.default_rng(0).random((32, 32, 3)) * 0.5
    plain, _ = develop(texture, CaptureSettings(), np.random.default_rng(0))
    noisy, _ = develop(texture, CaptureSettings(gain=5e-3, read=5e-3), np.random.default_rng(0))
    jpeg, view = develop(texture, CaptureSettings(jpeg_quality=60), np.random.default_rng(0))
    assert (noisy != plain).mean() > 0.5 and (jpeg != plain).mean() > 0.5 and view.jpeg_quality == 60


@pytest.mark.slow
def test_cli_photo_records_every_views_capture_in_scene_json(tmp_path):
    result = CliRunner().invoke(cli, ["synth", str(tmp_path / "s"), "--scenes", "1", "--views", "4",
                                      "--resolution", "32", "--workers", "1", "--layout", "handheld", "--photo"])
    assert result.exit_code == 0, result.output
    manifest = json.loads((tmp_path / "s" / "manifest.json").read_text())
    assert manifest["version"] == "synth-5" and manifest["options"]["capture"]["photo"] is True
    record = json.loads((tmp_path / "s" / "scene_00000" / "scene.json").read_text())
    views = record["views"]["train"] + record["views"]["test"]
    assert len(views) == 4
    assert all(v["vignetting"] == record["capture"]["vignetting"] > 0 for v in views)
    assert all(abs(v["exposure_stops"]) <= 0.5 and v["jpeg_quality"] > 0 for v in views)
    assert len({v["exposure_stops"] for v in views}) == 4  # drawn per view
