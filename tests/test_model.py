"""The generator's modules: shapes, finite gradients, projection against known pixels, aggregation weights,
config JSON round trip, and the two conditioning modes at about the same size."""
from __future__ import annotations

import dataclasses
import json

import pytest
import torch

from insertnerf_cli.config import ModelConfig, config_from_json, config_to_json
from insertnerf_cli.errors import UserError
from insertnerf_cli.model import EncodedViews, InsertNeRF, SourceViews
from insertnerf_cli.model.aggregate import ScaleAggregator, masked_softmax, weighted_moments
from insertnerf_cli.model.encoder import UNetEncoder
from insertnerf_cli.model.filter import SamplingFilter
from insertnerf_cli.model.hypernet import AppearanceHyper, GeometryHyperLayer, count_parameters
from insertnerf_cli.model.projection import project_samples
from insertnerf_cli.cameras.rays import rays_for_image
from model_fixtures import FAR, NEAR, TINY, orbit_cameras, sphere_views  # noqa: F401

pytestmark = pytest.mark.usefixtures("one_thread")


# ------------------------------------------------------------------ config
def test_config_json_round_trip():
    for cfg in (ModelConfig(), TINY, dataclasses.replace(TINY, conditioning="concat", background=(0.0, 0.0, 0.0))):
        text = json.dumps(config_to_json(cfg))
        back = config_from_json(ModelConfig, json.loads(text))
        assert back == cfg and isinstance(back.feature_dims, tuple)


def test_config_rejects_unknown_keys_and_bad_values():
    data = config_to_json(TINY)
    with pytest.raises(UserError, match="unknown key.*hyper_size"):
        config_from_json(ModelConfig, {**data, "hyper_size": 3})
    with pytest.raises(UserError, match="conditioning"):
        config_from_json(ModelConfig, {**data, "conditioning": "film"})
    with pytest.raises(UserError, match="expected 3 values"):
        config_from_json(ModelConfig, {**data, "feature_dims": [4, 4]})
    assert config_from_json(ModelConfig, {"nerf_width": 8}).nerf_width == 8  # missing keys take defaults


# ------------------------------------------------------------------ modules
def test_encoder_scales_for_sizes_not_multiple_of_16():
    enc = UNetEncoder((4, 6, 8, 10), (8, 6, 4), 4)
    feats = enc(torch.rand(2, 3, 48, 64))
    assert [tuple(f.shape) for f in feats] == [(2, 8, 6, 8), (2, 6, 12, 16), (2, 4, 24, 32)]
    assert all(torch.all(f >= 0) for f in feats)  # ReLU heads: the aggregation relies on it
    assert enc.reconstruct(feats[-1]).shape == (2, 3, 48, 64)


def test_projection_returns_the_colour_at_the_pixel_and_masks_unseen_points():
    torch.manual_seed(0)
    model = InsertNeRF(TINY).eval()
    cams = orbit_cameras(3, 20)
    images = torch.rand(3, 20, 20, 3)
    with torch.no_grad():
        encoded = model.encode(SourceViews(images, cams))
    rows, cols = torch.tensor([3, 10, 17]), torch.tensor([5, 12, 0])
    uv = torch.stack([cols + 0.5, rows + 0.5], -1).float()[None]  # pixel centres of view 0
    points = cams.subset([0]).unproject(uv, torch.full((1, 3), 2.5))[0]  # [3, 3]
    behind = 2 * cams.centers[0] - points[:1]  # mirrored through camera 0: behind it
    pts = torch.cat([points, behind])[:, None]  # [R=4, S=1, 3]
    seen = project_samples(encoded, pts, torch.randn(4, 3))
    torch.testing.assert_close(seen.colours[0, :, :3].T, images[0, rows, cols], atol=1e-5, rtol=1e-5)
    assert seen.mask[0, 0].tolist() == [1, 1, 1, 0]
    assert torch.all(seen.colours[0, :, 3] == 0) and all(torch.all(f[0, :, 3] == 0) for f in seen.features)
    assert seen.ray_diff.shape == (3, 4, 4) and torch.all(seen.cos.abs() <= 1 + 1e-5)


def test_projection_blends_colours_from_the_finer_photos_where_given():
    torch.manual_seed(0)
    model = InsertNeRF(TINY).eval()
    cams = orbit_cameras(3, 20)
    with torch.no_grad():
        encoded = model.encode(SourceViews(torch.rand(3, 20, 20, 3), cams))
    finer = torch.rand(3, 3, 40, 40)  # the same views' photos at twice the size
    rows, cols = torch.tensor([3, 21, 38]), torch.tensor([5, 30, 0])  # pixels of the finer photo
    uv = torch.stack([(cols + 0.5) / 2, (rows + 0.5) / 2], -1).float()[None]  # their centres in view 0's pixels
    points = cams.subset([0]).unproject(uv, torch.full((1, 3), 2.5))[0][:, None]  # [R=3, S=1, 3]
    plain = project_samples(encoded, points, torch.randn(3, 3))
    seen = project_samples(encoded.with_colours(finer), points, torch.randn(3, 3))
    torch.testing.assert_close(seen.blend_colours[0], finer[0, :, rows, cols], atol=1e-5, rtol=1e-5)
    assert plain.finer is None and not torch.allclose(plain.blend_colours[0], seen.blend_colours[0], atol=1e-2)
    # What the network reads is what it was trained on: colours, features and masks at the encoded size.
    torch.testing.assert_close(seen.colours, plain.colours)
    torch.testing.assert_close(seen.mask, plain.mask)
    for a, b in zip(seen.features, plain.features):
        torch.testing.assert_close(a, b)
    outside = (seen.mask == 0).expand_as(seen.finer)
    assert torch.all(seen.finer[outside] == 0)
    assert project_samples(encoded.with_colours(finer), points, torch.randn(3, 3), finer=False).finer is None
    kept = encoded.with_colours(finer).select([2, 0])
    torch.testing.assert_close(kept.colours, finer[[2, 0]])
    assert EncodedViews.join([kept, encoded.with_colours(finer).select([1])]).colours.shape == (3, 3, 40, 40)


def test_masked_softmax_and_moments():
    logits = torch.randn(5, 1, 7)
    mask = (torch.rand(5, 1, 7) > 0.4).float()
    mask[:, :, 0] = 0  # a sample no view sees
    w = masked_softmax(logits, mask)
    assert torch.all(w[mask == 0] == 0) and torch.all(w[:, :, 0] == 0)
    has = mask.amax(0)[0] > 0
    torch.testing.assert_close(w.sum(0)[0][has], torch.ones(int(has.sum())))
    values = torch.randn(5, 3, 7)
    mean, var = weighted_moments(values, w)
    ref_mean = (values * w).sum(0, keepdim=True)
    torch.testing.assert_close(mean, ref_mean)
    torch.testing.assert_close(var, ((values - ref_mean) ** 2 * w).sum(0, keepdim=True), atol=1e-5, rtol=1e-4)


def test_static_weights_prefer_views_along_the_query_ray():
    agg = ScaleAggregator(4, 2, 4, sharpness_init=5.0)
    cos = torch.tensor([1.0, 0.9, 0.0, -0.5]).reshape(4, 1, 1)
    mask = torch.tensor([1.0, 1.0, 1.0, 0.0]).reshape(4, 1, 1)
    w = agg.static_weights(cos, mask)[:, 0, 0]
    assert w[0] > w[1] > w[2] and w[3] == 0
    torch.testing.assert_close(w.sum(), torch.tensor(1.0))


def test_module_shapes_and_gradients():
    r, s, d = 3, 8, 5
    cond = torch.randn(r, s, d, requires_grad=True)
    x = torch.randn(r, s, 6, requires_grad=True)
    outs = [SamplingFilter(d, s, 2)(cond), GeometryHyperLayer(d, s, 6, 7, 4, 2)(x, cond),
            AppearanceHyper(d, s, 6, 3, 2)(x, cond)]
    assert [tuple(o.shape) for o in outs] == [(r, s, d), (r, s, 7), (r, s, 6)]
    agg = ScaleAggregator(6, 3, 4, 0.2)
    feats = torch.rand(4, 6, r * s, requires_grad=True)
    desc, dyn = agg(feats, torch.ones(4, 1, r * s), torch.randn(4, 4, r * s))
    assert desc.shape == (r * s, agg.out_dim) and dyn.shape == (4, 1, r * s)
    sum(o.sum() for o in outs).add(desc.sum() + (dyn * torch.randn_like(dyn)).sum()).backward()
    for t in (cond, x, feats):
        assert t.grad is not None and torch.isfinite(t.grad).all() and t.grad.abs().sum() > 0


@pytest.mark.slow
@pytest.mark.parametrize("conditioning", ["hyper", "concat"])
def test_full_model_forward_losses_and_finite_gradients_everywhere(conditioning):
    torch.manual_seed(0)
    model = InsertNeRF(dataclasses.replace(TINY, conditioning=conditioning)).train()
    views = sphere_views(3, 24)
    encoded = model.encode(views)
    assert [f.shape[-1] for f in encoded.features] == [4, 8, 16]  # padded 24 -> 32: 1/8, 1/4, 1/2
    rays = rays_for_image(orbit_cameras(1, 24, phase=0.5), torch.tensor([NEAR]), torch.tensor([FAR]))[:40]
    out = model(encoded, rays, train=True)
    for part in (out.coarse, out.fine):
        assert part.rgb.shape == (40, 3) and part.depth.shape == (40,) and part.opacity.shape == (40,)
        assert part.weights.shape == (40, 16) and torch.all(part.weights.sum(-1) <= 1 + 1e-5)
    terms = model.losses(out, torch.rand(40, 3), encoded)
    assert terms.backbone > 0 and terms.dynamic > 0 and torch.isfinite(terms.total)
    terms.total.backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None]
    assert not missing, f"parameters without gradient: {missing}"
    assert all(torch.isfinite(p.grad).all() for p in model.parameters())


@pytest.mark.parametrize("conditioning,consistency", [("hyper", 0.0), ("concat", 0.0), ("hyper", 0.01)])
def test_inference_render_matches_the_fine_pass_of_forward(conditioning, consistency):
    """model.render skips the coarse appearance branch; what it returns must not change (with the
    photo-consistency cue on both passes too)."""
    torch.manual_seed(1)
    model = InsertNeRF(dataclasses.replace(TINY, conditioning=conditioning, consistency_temperature_coarse=consistency,
                                           consistency_temperature_fine=consistency)).eval()
    with torch.no_grad():
        for p in model.parameters():  # away from the initialisation, so that every branch matters
            p.add_(0.3 * torch.randn_like(p))
    views = sphere_views(3, 24)
    rays = rays_for_image(orbit_cameras(1, 24, phase=0.5), torch.tensor([NEAR]), torch.tensor([FAR]))[:50]
    with torch.inference_mode():
        encoded = model.encode(views)
        full = model(encoded, rays, train=False).fine
        fast = model.render(encoded, rays)
    assert full.rgb.std() > 1e-3
    for name in ("rgb", "depth", "opacity", "weights", "t"):
        torch.testing.assert_close(getattr(fast, name), getattr(full, name), rtol=0, atol=1e-6)


def test_eval_encode_has_no_reconstruction_and_separate_fine_head_allows_other_counts():
    cfg = dataclasses.replace(TINY, separate_fine_head=True, samples_fine=24)
    model = InsertNeRF(cfg).eval()
    with torch.no_grad():
        encoded = model.encode(sphere_views(2, 16))
        rays = rays_for_image(orbit_cameras(1, 4), torch.tensor([NEAR]), torch.tensor([FAR]))
        out = model(encoded, rays, train=False)
    assert encoded.reconstruction is None and out.fine.weights.shape == (16, 24)
    assert model.fine_head is not model.coarse_head
    with pytest.raises(ValueError, match="samples_coarse == samples_fine"):
        ModelConfig(samples_coarse=32, samples_fine=64)


def test_concat_ablation_has_about_the_same_parameter_count():
    for cfg in (TINY, ModelConfig()):
        hyper = count_parameters(InsertNeRF(cfg))
        concat = count_parameters(InsertNeRF(dataclasses.replace(cfg, conditioning="concat")))
        print(f"parameters: hyper {hyper}, concat {concat}")
        assert abs(hyper - concat) / hyper < 0.02
