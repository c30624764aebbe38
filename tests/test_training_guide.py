"""Round 20: training places the fine samples as render does with SfM points (training/guide.py)."""
from __future__ import annotations

import dataclasses

import pytest
import torch

from insertnerf_cli.model import InsertNeRF
from insertnerf_cli.cameras.rays import rays_from_pixels
from insertnerf_cli.training import train
from insertnerf_cli.training.guide import COVERAGE, RELATIVE_ERROR, WRONG, simulated_prior
from model_fixtures import TINY, flat_views, orbit_cameras
from test_geometry_training import synth_root, synth_set  # noqa: F401  (synth_set: the module's fixture of 2 synth scenes)
from test_train import small

pytestmark = pytest.mark.usefixtures("one_thread")


def test_the_simulated_prior_is_sparse_close_to_the_surface_and_absent_where_none_is():
    torch.manual_seed(0)
    depth = torch.full((20000,), 3.0)
    depth[:5000] = 0.0  # no surface: a sky or an object scene's plain backdrop
    depth[5000:6000] = float("nan")  # unknown: a scene without depth files
    prior = simulated_prior(depth)
    assert torch.isnan(prior[:6000]).all()
    given = prior[6000:][torch.isfinite(prior[6000:])]
    assert abs(len(given) / 14000 - COVERAGE) < 0.02
    error = (given / 3.0).log().abs()
    # One depth here, so a wrong donor is right too: every prior lies within the noise of the surface.
    assert error.median() < RELATIVE_ERROR and error.max() < 6 * RELATIVE_ERROR
    assert torch.isnan(simulated_prior(torch.zeros(10))).all()  # no surface at all: no donor, no prior


def test_wrong_priors_carry_another_rays_depth():
    torch.manual_seed(1)
    depth = torch.cat([torch.full((10000,), 2.0), torch.full((10000,), 4.0)])
    prior = simulated_prior(depth)
    near = prior[:10000][torch.isfinite(prior[:10000])]
    far_share = float((near > 3.0).float().mean())  # rays at 2 that got a depth near 4 from a donor
    assert abs(far_share - WRONG / 2) < 0.015


def fine_share_near(model: InsertNeRF, guide: torch.Tensor | None, depth: float) -> float:
    views = flat_views([(0.5, 0.5, 0.5)] * 4)
    target = orbit_cameras(1, 16, phase=0.3)
    uv = torch.rand(64, 2)[None] * 16
    rays = rays_from_pixels(target, uv, torch.tensor([1.0]), torch.tensor([5.0]))
    with torch.no_grad():
        out = model(model.encode(views), rays, train=True, guide=guide)
    return float(((out.fine_samples.t - depth).abs() < 0.3).float().mean())


def test_a_guide_sends_the_fine_samples_to_its_depth_and_nan_leaves_them_alone():
    torch.manual_seed(0)
    model = InsertNeRF(dataclasses.replace(TINY, samples_coarse=16, samples_fine=16, separate_fine_head=True))
    torch.manual_seed(2)
    plain = fine_share_near(model, None, 4.0)
    torch.manual_seed(2)
    guided = fine_share_near(model, torch.full((64,), 4.0), 4.0)
    torch.manual_seed(2)
    unguided = fine_share_near(model, torch.full((64,), float("nan")), 4.0)
    assert guided > plain + 0.4 and guided > 0.6
    assert unguided == pytest.approx(plain)


@pytest.mark.slow
def test_training_with_the_guide_runs_and_is_saved_with_the_run(synth_set, tmp_path):  # noqa: F811
    from insertnerf_cli.training.config import saved_train_config

    result = train(synth_set, tmp_path / "run", small(model=dataclasses.replace(TINY, num_views=4), steps=2,
                                                      val_scenes=1, guide_prior=True), torch.device("cpu"))
    assert result.step == 2
    assert saved_train_config(tmp_path / "run" / "checkpoints" / "last.pt").guide_prior


@pytest.fixture(scope="module")
def textured_set(tmp_path_factory):
    """Synth scenes at 64 px: enough pixels for a few corners per view (CORNERS_PER_PIXEL)."""
    return synth_root(tmp_path_factory, "featureprior", resolution=64, layout="forward", seed=7)


def feature_priors(root, budget_mb: int):
    from insertnerf_cli.training.data import find_scenes
    from insertnerf_cli.training.device_data import load_training_set
    from insertnerf_cli.training.feature_prior import FeaturePriors

    scenes = find_scenes(root, 64, print, show_progress=False)
    data = load_training_set(scenes, budget_mb, torch.device("cpu"), print, show_progress=False, with_depth=True)
    return data, FeaturePriors(data)


@pytest.mark.slow
def test_the_feature_prior_lies_on_the_true_surface_from_the_sources_corners_alone(textured_set):
    data, priors = feature_priors(textured_set, 64)
    g = data.groups[0]
    pixels = torch.arange(g.height * g.width)[None]  # [1, H * W]
    sources = torch.arange(1, int(g.n_train[0]))[None]  # the other training views of scene 0
    prior = priors.step_prior(0, torch.tensor([0]), sources, pixels)
    true = g.depths[0].reshape(-1)
    given = torch.isfinite(prior) & (true > 0)
    assert 0.2 < float(given.float().mean()) <= 1.0
    assert float(((prior[given] - true[given]).abs() / true[given]).median()) < 0.1
    # The target's own corners are never used (eval leaves the held-out photo out): with itself as its only
    # source the target gets no prior at all.
    assert torch.isnan(priors.step_prior(0, torch.tensor([0]), torch.tensor([[0, 0]]), pixels)).all()
    # A set streamed from disk (budget 0) gives the same prior as one kept in memory.
    streamed_data, streamed = feature_priors(textured_set, 0)
    assert streamed_data.groups[0].images is None
    again = streamed.step_prior(0, torch.tensor([0]), sources, pixels)
    assert torch.equal(torch.isnan(again), torch.isnan(prior))
    assert torch.allclose(again[given], prior[given])


@pytest.mark.slow
def test_training_with_the_feature_prior_runs_and_is_saved_with_the_run(textured_set, tmp_path):
    from insertnerf_cli.training.config import saved_train_config

    config = small(model=dataclasses.replace(TINY, num_views=4), steps=2, val_scenes=1, resolution=64,
                   guide_prior=True, guide_from="features")
    assert train(textured_set, tmp_path / "run", config, torch.device("cpu")).step == 2
    assert saved_train_config(tmp_path / "run" / "checkpoints" / "last.pt").guide_from == "features"
