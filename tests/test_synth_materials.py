"""insertnerf synth (synth-5) materials: textures with natural image statistics, and mirror coats."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.synth.drawing import flat_texture, sky_image
from insertnerf_cli.synth.geometry import Shape, trimesh_box
from insertnerf_cli.synth.layouts import look_at
from insertnerf_cli.synth.natural import NATURAL, dead_leaves, pink, pink_texture
from insertnerf_cli.synth.raycast import build_scene_mesh
from insertnerf_cli.synth.render import render_view
from insertnerf_cli.synth.shading import sky_radiance
from insertnerf_cli.synth.textures import Texture
from insertnerf_cli.synth.world import Material, Placed, Stage, World

SIZE = 128


def _radial_slope(field: np.ndarray) -> float:
    """Slope of log amplitude against log frequency, over 4-40 cycles per tile."""
    amplitude = np.abs(np.fft.fft2(field))
    f = np.fft.fftfreq(field.shape[0]) * field.shape[0]
    k = np.sqrt(f[:, None] ** 2 + f[None, :] ** 2)
    bins = np.arange(4, 41)
    means = [amplitude[(k >= b) & (k < b + 1)].mean() for b in bins]
    return float(np.polyfit(np.log(bins + 0.5), np.log(means), 1)[0])


@pytest.mark.parametrize("exponent", [0.8, 1.0, 1.3])
def test_pink_noise_has_a_one_over_f_amplitude_spectrum(exponent):
    field = pink(np.random.default_rng(0), SIZE, exponent)
    assert _radial_slope(field) == pytest.approx(-exponent, abs=0.12)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(NATURAL))
def test_natural_textures_tile_and_stay_in_range(name):
    for seed in range(3):
        image = NATURAL[name](np.random.default_rng(seed), SIZE)
        assert image.shape == (SIZE, SIZE, 3) and image.min() >= 0 and image.max() <= 1 and image.std() > 0.01
        # Across the tile's edge the image changes no more than between neighbouring columns inside it.
        seam = np.abs(image[:, 0] - image[:, -1]).mean() + np.abs(image[0] - image[-1]).mean()
        inside = np.abs(np.diff(image, axis=1)).mean() + np.abs(np.diff(image, axis=0)).mean()
        assert seam < 2.0 * inside + 1e-3


def test_pink_texture_varies_in_brightness_far_more_than_in_hue():
    image = pink_texture(np.random.default_rng(3), SIZE) + 1e-3
    brightness = np.log(image.mean(axis=-1))
    hue = np.log(image[..., 0] / image[..., 2])
    assert brightness.std() > 2 * hue.std()


def test_dead_leaves_are_flat_patches_occluding_each_other():
    image = dead_leaves(np.random.default_rng(0), 256)
    flat = (np.abs(np.diff(image, axis=1)).max(axis=-1) < 1e-6).mean()
    assert flat > 0.3  # inside a leaf the colour is constant
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 50  # many leaves of many shades


def _mirror_world(mirror: float) -> World:
    sky = Material(Texture.from_image(sky_image(np.random.default_rng(0), 64)), 1.0, mapping="sky", name="sky")
    black = Material(flat_texture(np.zeros(3)), 1.0, mirror=mirror, name="coat")
    board = Placed(Shape(trimesh_box(np.array([4.0, 0.1, 4.0])), smooth=False, kind="box"), np.eye(3),
                   np.array([0.0, 3.0, 0.0]), 1.0, 0)
    return World((board,), (black,), (), Stage(np.zeros(3), 1.0), np.zeros(3), np.zeros(3), np.zeros(3), sky=sky)


def test_a_mirror_coat_shows_the_sky_behind_the_camera_and_a_matte_black_board_does_not():
    c2w = look_at(np.array([[0.0, 0.0, 0.3]]), np.array([[0.0, 3.0, 0.3]]), np.zeros(1))
    camera = Cameras(intrinsics(20.0, 20.0, 8.0, 8.0)[None], torch.from_numpy(c2w), 16, 16)
    mirrored = render_view(build_scene_mesh(_mirror_world(1.0)), _mirror_world(1.0), camera)
    matte = render_view(build_scene_mesh(_mirror_world(0.0)), _mirror_world(0.0), camera)
    assert np.abs(matte.radiance).max() == 0  # no light, black albedo, no coat
    # A flat mirror facing +-y sends a ray (x, y, z) back as (x, -y, z): into the sky behind the camera.
    directions = camera.ray_directions(camera.pixel_grid().reshape(1, -1, 2))[0].numpy()
    expected = sky_radiance(_mirror_world(1.0).sky, directions * np.array([1.0, -1.0, 1.0]), 20.0)
    np.testing.assert_allclose(mirrored.radiance.reshape(-1, 3), expected, atol=2e-3)
    assert (mirrored.depth > 2.9).all() and (mirrored.depth < 3.0).all()  # depth stays the board's
