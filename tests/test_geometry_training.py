"""Issue 27: geometry supervision from synth's exact depth, the sample at infinity, a varying view count."""
from __future__ import annotations

import dataclasses
import json

import pytest
import torch

from insertnerf_cli.model import InsertNeRF, SourceViews
from insertnerf_cli.model.geometry_losses import depth_loss, distortion_loss
from insertnerf_cli.cameras.rays import rays_from_pixels
from insertnerf_cli.synth import SynthOptions, generate_dataset
from insertnerf_cli.training import train
from insertnerf_cli.training.batches import DrawGenerators, StepStream, check_batch_scenes
from insertnerf_cli.training.data import find_scenes
from insertnerf_cli.training.device_data import load_training_set
from model_fixtures import TINY, flat_views, orbit_cameras
from test_train import small

pytestmark = pytest.mark.usefixtures("one_thread")

EDGES = torch.linspace(1.0, 5.0, 9)[None]  # [1, 9]: 8 bins of width 0.5 from t = 1 to 5


def one_hot(bin_index: int, mass: float = 1.0) -> torch.Tensor:
    weights = torch.zeros(1, 8)
    weights[0, bin_index] = mass
    return weights


def test_depth_term_is_zero_at_the_true_depth_and_positive_elsewhere():
    depth = torch.tensor([2.2])  # inside bin 2 = [2.0, 2.5)
    assert depth_loss(one_hot(2), EDGES, depth) == 0.0
    assert depth_loss(one_hot(6), EDGES, depth) > 0.0  # mass at the wrong depth
    assert depth_loss(one_hot(2, 0.5), EDGES, depth) == pytest.approx(0.5)  # half the ray left transparent
    farther = depth_loss(one_hot(7), EDGES, depth)
    assert farther > depth_loss(one_hot(4), EDGES, depth) > 0.0  # grows with the distance from the surface


def test_depth_term_of_a_ray_without_surface_is_its_opacity_and_unknown_depths_count_for_nothing():
    weights = torch.cat([one_hot(3, 0.25), one_hot(3), one_hot(2)])
    depth = torch.tensor([0.0, float("nan"), 2.2])  # no surface, unknown, a surface in bin 2
    assert depth_loss(weights[:1], EDGES[:1], depth[:1]) == pytest.approx(0.25)
    assert depth_loss(weights[:1] * 0, EDGES[:1], depth[:1]) == 0.0
    edges = EDGES.expand(3, -1)
    assert depth_loss(weights, edges, depth) == pytest.approx(0.25 / 2)  # mean over the two known rays
    assert depth_loss(weights[1:2], EDGES, depth[1:2]) == 0.0


def test_distortion_prefers_one_compact_peak_to_mass_spread_along_the_ray():
    near, far = torch.tensor([1.0]), torch.tensor([5.0])
    peak = distortion_loss(one_hot(3), EDGES, near, far, in_disparity=False)
    spread = distortion_loss(torch.full((1, 8), 1.0 / 8), EDGES, near, far, in_disparity=False)
    assert 0.0 < peak < spread
    assert distortion_loss(torch.zeros(1, 8), EDGES, near, far, in_disparity=True) == 0.0


def empty_model(infinity: bool) -> InsertNeRF:
    """A field with no density anywhere (softplus(-60) ~ 1e-26): every ray shows its backdrop."""
    torch.manual_seed(0)
    config = dataclasses.replace(TINY, infinity_sample=infinity, density_bias=-60.0, background=(1.0, 1.0, 1.0))
    return InsertNeRF(config).eval()


def render_centre(model: InsertNeRF, views: SourceViews) -> torch.Tensor:
    target = orbit_cameras(1, 16, phase=0.3)
    uv = torch.tensor([[[8.0, 8.0]]])
    rays = rays_from_pixels(target, uv, torch.tensor([1.5]), torch.tensor([4.5]))
    with torch.no_grad():
        return model.render(model.encode(views), rays).rgb[0]


def test_the_sample_at_infinity_takes_its_colour_from_the_reference_views():
    grey = (0.2, 0.4, 0.6)
    assert torch.allclose(render_centre(empty_model(True), flat_views([grey] * 4)), torch.tensor(grey), atol=1e-5)
    # One colour per view: a blend of the views' colours, never the fixed white background.
    colours = [(0.9, 0.1, 0.1), (0.1, 0.9, 0.1), (0.1, 0.1, 0.9), (0.5, 0.5, 0.1)]
    rgb = render_centre(empty_model(True), flat_views(colours))
    assert torch.all(rgb >= 0.1 - 1e-5) and torch.all(rgb <= 0.9 + 1e-5) and rgb.sum() < 2.5
    assert torch.allclose(render_centre(empty_model(False), flat_views(colours)), torch.ones(3), atol=1e-5)


def test_a_direction_no_view_sees_falls_back_to_the_background():
    model = empty_model(True)
    views = flat_views([(0.2, 0.4, 0.6)] * 4)
    # Straight up from above the cameras: no view (all looking sideways at the origin) sees the zenith.
    rays = rays_from_pixels(orbit_cameras(1, 16, height=1.0), torch.tensor([[[8.0, 8.0]]]), torch.tensor([1.5]),
                            torch.tensor([4.5]))
    up = type(rays)(rays.origins, torch.tensor([[0.0, 0.0, 1.0]]), rays.near, rays.far)
    with torch.no_grad():
        assert torch.allclose(model.backdrop(model.encode(views), up)[0], torch.ones(3))


def synth_root(tmp_path_factory, name: str, **options):
    """A folder of 2 synth scenes of 8 views (1 held out) with their depth files; ``options`` as SynthOptions."""
    root = tmp_path_factory.mktemp(name)
    generate_dataset(root, SynthOptions(scenes=2, views=8, test_views=1, **options), workers=1)
    return root


@pytest.fixture(scope="module")
def synth_set(tmp_path_factory):
    return synth_root(tmp_path_factory, "synthdepth", resolution=32, layout="mixed", seed=5)


@pytest.mark.slow
def test_training_views_carry_synths_true_depth(synth_set):
    scenes = find_scenes(synth_set, 32, print, show_progress=False)
    data = load_training_set(scenes, 64, torch.device("cpu"), print, show_progress=False, with_depth=True)
    depths = torch.cat([g.depths.reshape(-1) for g in data.groups])
    assert torch.isfinite(depths).all() and (depths > 0).any()
    stream = StepStream(data, check_batch_scenes(data, 1, 16), DrawGenerators(torch.device("cpu"), 0), 1, 6, 16,
                        1 << 20, views_min=2)
    counts = set()
    for _ in range(30):
        draw, batch = stream.next()
        counts.add(draw.sources.shape[1])
        assert batch.target_depth.shape == (16,) and len(batch.views) == draw.sources.shape[1]
    assert counts <= set(range(2, 7)) and len(counts) >= 3  # the count varies within views_min..num_views


@pytest.mark.slow
def test_training_with_depth_distortion_infinity_and_varying_views(synth_set, tmp_path):
    model = dataclasses.replace(TINY, num_views=4, infinity_sample=True, loss_depth_weight=0.1,
                                loss_distortion_weight=0.01)
    result = train(synth_set, tmp_path / "run", small(model=model, steps=3, views_min=2, val_scenes=1),
                   torch.device("cpu"))
    assert result.step == 3
    lines = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    logged = [line for line in lines if line.get("split") == "train"]
    assert logged and all(line["depth"] > 0 and line["distortion"] > 0 for line in logged)


@pytest.mark.slow
def test_the_visibility_cue_starts_neutral_and_warm_starts_from_a_model_without_it(tmp_path):
    from insertnerf_cli.model.checkpoint import read_checkpoint, save_checkpoint
    from insertnerf_cli.training.warm_start import warm_start

    views = flat_views([(0.9, 0.1, 0.1), (0.1, 0.9, 0.1), (0.1, 0.1, 0.9), (0.5, 0.5, 0.1)])
    torch.manual_seed(0)
    plain = InsertNeRF(TINY).eval()
    save_checkpoint(tmp_path / "plain.pt", plain, TINY)
    cued = InsertNeRF(dataclasses.replace(TINY, visibility_cue=True)).eval()
    started = warm_start(cued, read_checkpoint(tmp_path / "plain.pt"))
    assert started.resampled == 0
    assert torch.allclose(render_centre(cued, views), render_centre(plain, views), atol=1e-6)
    with torch.no_grad():  # once the cue has weights, the views' disagreement changes the picture
        for agg in cued.aggregators:
            agg.dynamic_deviation.weight.fill_(5.0)
    assert not torch.allclose(render_centre(cued, views), render_centre(plain, views), atol=1e-4)
