"""Round 20: fine-tuning places its fine samples as render does, by the scene's SfM points (finetune.TargetPriors)."""
from __future__ import annotations

import pytest
import torch
from cli_fixtures import make_checkpoint

from insertnerf_cli.finetune import FinetuneConfig, finetune
from insertnerf_cli.finetune import loop as finetune_loop
from insertnerf_cli.finetune.data import TargetPriors, finetune_scene
from insertnerf_cli.scenes.points import ScenePoints
from scene_fixtures import known_scene, write_colmap

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def colmap_scene(tmp_path_factory):
    return write_colmap(tmp_path_factory.mktemp("ftprior") / "scene", known_scene(9))


def test_every_usable_view_gets_a_prior_at_its_points_depths(colmap_scene):
    scene = finetune_scene(colmap_scene, 32)
    priors = TargetPriors(scene, torch.device("cpu"))
    assert set(priors.flat) == set(scene.train_ids)
    points = scene.scene.points.xyz
    for target in scene.train_ids:
        camera = scene.cameras.subset([target]).to(dtype=torch.float64)
        z = (points @ camera.w2c[0, :3, :3].T + camera.w2c[0, :3, 3])[:, 2]
        prior = priors.flat[target]
        seen = prior[torch.isfinite(prior)].double()
        assert len(seen) > 0.2 * len(prior)
        assert float(seen.min()) >= float(z.min()) - 1e-4 and float(seen.max()) <= float(z.max()) + 1e-4
    pixels = torch.tensor([0, 5, 17])
    torch.testing.assert_close(priors.guide(scene.train_ids[0], pixels), priors.flat[scene.train_ids[0]][pixels],
                               equal_nan=True)


@pytest.mark.slow
def test_a_step_passes_the_targets_prior_to_the_model_unless_told_not_to(colmap_scene, tmp_path, monkeypatch):
    base = make_checkpoint(tmp_path / "base.pt")
    guides = []
    real_forward = finetune_loop.InsertNeRF.forward

    def recording_forward(self, encoded, rays, train, guide=None):
        guides.append(guide)
        return real_forward(self, encoded, rays, train, guide)

    monkeypatch.setattr(finetune_loop.InsertNeRF, "forward", recording_forward)
    for sfm_depth in (True, False):
        guides.clear()
        config = FinetuneConfig(minutes=None, steps=3, rays=16, views=3, resolution=32, sfm_depth=sfm_depth)
        result = finetune(colmap_scene, tmp_path / f"ft_{sfm_depth}.pt", config, torch.device("cpu"), base=base)
        assert result.steps == 3 and len(guides) == 3
        if sfm_depth:
            assert all(g is not None and g.shape == (16,) and torch.isfinite(g).any() for g in guides)
        else:
            assert all(g is None for g in guides)


@pytest.mark.slow
def test_points_a_caller_already_has_are_used_instead_of_the_scenes_own(colmap_scene, tmp_path, monkeypatch):
    """render --finetune triangulates once and hands its points on; the fine-tune must use them."""
    base = make_checkpoint(tmp_path / "base.pt")
    own = finetune_scene(colmap_scene, 32).scene.points
    given = ScenePoints(own.xyz + 0.01, own.observed)
    seen = []

    class RecordingPriors(TargetPriors):
        def __init__(self, scene, device):
            seen.append(scene.scene.points)
            super().__init__(scene, device)

    monkeypatch.setattr(finetune_loop, "TargetPriors", RecordingPriors)
    config = FinetuneConfig(minutes=None, steps=1, rays=16, views=3, resolution=32)
    finetune(colmap_scene, tmp_path / "given.pt", config, torch.device("cpu"), base=base, points=given)
    finetune(colmap_scene, tmp_path / "own.pt", config, torch.device("cpu"), base=base)
    assert seen[0] is given
    torch.testing.assert_close(seen[1].xyz, own.xyz)


@pytest.mark.slow
def test_each_target_is_drawn_out_to_the_far_bound_render_would_give_it(tmp_path, monkeypatch):
    """Round 26: where a scene's far bounds stop short of its points, render raises a frame's far bound to cover
    them; the fine-tune trains each target's rays within the bound render would give that view."""
    from dataclasses import replace

    from scene_fixtures import write_llff

    known = known_scene(9)
    root = write_colmap(tmp_path / "tight", known)
    write_llff(root, replace(known, far=known.near + 0.3 * (known.far - known.near)))
    given = finetune_scene(root, 32).far
    base = make_checkpoint(tmp_path / "base.pt")
    fars = []
    real_forward = finetune_loop.InsertNeRF.forward

    def recording_forward(self, encoded, rays, train, guide=None):
        fars.append(float(rays.far[0]))
        return real_forward(self, encoded, rays, train, guide)

    monkeypatch.setattr(finetune_loop.InsertNeRF, "forward", recording_forward)
    for sfm_depth in (True, False):
        fars.clear()
        config = FinetuneConfig(minutes=None, steps=4, rays=16, views=3, resolution=32, sfm_depth=sfm_depth)
        finetune(root, tmp_path / f"ft_{sfm_depth}.pt", config, torch.device("cpu"), base=base)
        nearest = [float((given - f).abs().min()) for f in fars]
        if sfm_depth:
            assert min(nearest) > 1e-3 and min(fars) > float(given.min())  # raised, as every target's bound cut
        else:
            assert max(nearest) < 1e-5  # each step's far bound is its target's own
