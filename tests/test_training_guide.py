"""Round 20: training places the fine samples as render does with SfM points (training/guide.py)."""
from __future__ import annotations

import dataclasses

import pytest
import torch

from insertnerf_cli.model import InsertNeRF
from insertnerf_cli.rays import rays_from_pixels
from insertnerf_cli.training import train
from insertnerf_cli.training.guide import COVERAGE, RELATIVE_ERROR, WRONG, simulated_prior
from model_fixtures import TINY, flat_views, orbit_cameras
from test_geometry_training import synth_set  # noqa: F401  (the module's fixture of 2 synth scenes)
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


def test_training_with_the_guide_runs_and_is_saved_with_the_run(synth_set, tmp_path):  # noqa: F811
    from insertnerf_cli.training.config import saved_train_config

    result = train(synth_set, tmp_path / "run", small(model=dataclasses.replace(TINY, num_views=4), steps=2,
                                                      val_scenes=1, guide_prior=True), torch.device("cpu"))
    assert result.step == 2
    assert saved_train_config(tmp_path / "run" / "checkpoints" / "last.pt").guide_prior
