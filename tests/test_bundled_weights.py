"""The pretrained generator shipped in the package loads safely and renders."""
import pytest
import torch

from insertnerf_cli.errors import UserError
from insertnerf_cli.model.checkpoint import bundled_checkpoint, load_model
from insertnerf_cli.rendering.image_renderer import render_image
from model_fixtures import FAR, NEAR, orbit_cameras, sphere_views

MAX_BYTES = 25 * 2**20


def test_bundled_checkpoint_is_small_and_loads_with_weights_only():
    path = bundled_checkpoint()
    assert path.stat().st_size <= MAX_BYTES
    payload = torch.load(path, map_location="cpu", weights_only=True)
    assert "model" in payload and "train" not in payload  # weights and config only


@pytest.mark.slow
def test_bundled_model_renders_a_finite_image(one_thread):
    model, _ = load_model(bundled_checkpoint(), torch.device("cpu"))
    size = 24
    encoded = model.encode(sphere_views(3, size))
    out = render_image(model, encoded, orbit_cameras(1, size, phase=0.4), NEAR, FAR)
    assert out.rgb.shape == (size, size, 3)
    assert torch.isfinite(out.rgb).all() and torch.isfinite(out.depth).all()
    assert ((out.depth >= NEAR - 1e-4) & (out.depth <= FAR + 1e-4)).all()


@pytest.mark.slow
def test_bundled_fast_model_is_the_default_and_takes_fewer_samples_than_full(one_thread):
    path = bundled_checkpoint("fast")
    assert path == bundled_checkpoint()
    full = bundled_checkpoint("full")
    assert full.stat().st_size <= MAX_BYTES
    _, config = load_model(path, torch.device("cpu"))
    model, full_config = load_model(full, torch.device("cpu"))
    assert config.samples_coarse + config.samples_fine < full_config.samples_coarse + full_config.samples_fine
    size = 24
    out = render_image(model, model.encode(sphere_views(3, size)), orbit_cameras(1, size, phase=0.4), NEAR, FAR)
    assert torch.isfinite(out.rgb).all() and ((out.depth >= NEAR - 1e-4) & (out.depth <= FAR + 1e-4)).all()


def test_the_bundled_nerfpp_generator_has_that_backbone_and_only_fast_has_one():
    path = bundled_checkpoint("fast", "nerfpp")
    assert path.stat().st_size <= MAX_BYTES and path != bundled_checkpoint()
    _, config = load_model(path, torch.device("cpu"))
    assert config.backbone == "nerfpp" and config.samples_background > 0
    assert load_model(bundled_checkpoint(), torch.device("cpu"))[1].backbone == "nerf"
    with pytest.raises(UserError, match="no bundled full generator has the nerfpp backbone"):
        bundled_checkpoint("full", "nerfpp")
