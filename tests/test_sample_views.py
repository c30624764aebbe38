"""Issue 27: each sample aggregates only its K reference views nearest in angle (ModelConfig.sample_views); the
inference-only settings (this and colour_prior_views) in the checkpoint config."""
from __future__ import annotations

import dataclasses

import pytest
import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.config import ModelConfig, config_from_json, config_to_json
from insertnerf_cli.model import InsertNeRF, SourceViews
from insertnerf_cli.model.projection import Projected, ray_angle
from insertnerf_cli.cameras.rays import rays_from_pixels
from model_fixtures import RADIUS, TINY, orbit_cameras

pytestmark = pytest.mark.usefixtures("one_thread")


def projected_at(angles: list[float], mask: list[float]) -> Projected:
    """One sample seen by views whose rays make ``angles`` with the query ray; every tensor tags its view."""
    query = torch.tensor([0.0, 0.0, 1.0])
    a = torch.tensor(angles)
    refs = torch.stack([torch.sin(a), torch.zeros_like(a), torch.cos(a)], dim=-1)  # [V, 3]
    ray_diff = torch.cat([refs - query, (refs @ query)[:, None]], dim=1)[:, :, None]  # [V, 4, 1]
    tag = torch.arange(len(angles), dtype=torch.float32)[:, None, None]  # [V, 1, 1]: view n holds n
    return Projected((tag.expand(-1, 2, 1), tag.expand(-1, 5, 1)), tag.expand(-1, 3, 1),
                     torch.tensor(mask)[:, None, None], ray_diff, tag.expand(-1, 3, 1))


def test_ray_angle_is_the_angle_between_the_rays():
    angles = [0.0, 0.1, 0.7, 2.5]
    seen = projected_at(angles, [1.0] * 4)
    assert torch.allclose(ray_angle(seen.ray_diff)[:, 0, 0], torch.tensor(angles), atol=1e-5)


def test_the_k_nearest_valid_views_in_angle_are_kept_with_everything_they_see():
    seen = projected_at([0.4, 0.1, 0.3, 0.2, 0.05], [1.0, 1.0, 1.0, 1.0, 0.0])  # view 4 misses the sample
    near = seen.nearest_in_angle(3)
    kept = sorted(int(v) for v in near.colours[:, 0, 0])
    assert kept == [1, 2, 3]  # 0.1, 0.2, 0.3: the hidden view 4 is nearer but cannot count
    for tensor in (*near.features, near.colours, near.finer):
        assert tensor.shape[0] == 3 and torch.equal(tensor[:, 0, 0], near.colours[:, 0, 0])
    assert torch.all(near.mask == 1.0)
    assert torch.allclose(ray_angle(near.ray_diff)[:, 0, 0].sort().values, torch.tensor([0.1, 0.2, 0.3]), atol=1e-5)


def test_with_no_more_views_than_k_nothing_changes():
    seen = projected_at([0.4, 0.1], [1.0, 1.0])
    assert seen.nearest_in_angle(2) is seen and seen.nearest_in_angle(8) is seen


def render_centre(views: SourceViews, sample_views: int) -> torch.Tensor:
    """The fine colour [3] of the centre pixel of a target camera beside view 0 of the orbit, sampled within
    0.5 of the origin, where every view sees every sample (so no farther view stands in for a hidden one)."""
    torch.manual_seed(0)
    model = InsertNeRF(dataclasses.replace(TINY, sample_views=sample_views)).eval()
    target = orbit_cameras(1, 16, phase=0.05)
    rays = rays_from_pixels(target, torch.tensor([[[8.0, 8.0]]]), torch.tensor([RADIUS - 0.5]),
                            torch.tensor([RADIUS + 0.5]))
    with torch.no_grad():
        return model.render(model.encode(views), rays).rgb[0]


def subset(views: SourceViews, ids: list[int]) -> SourceViews:
    return SourceViews(views.images[ids], views.cameras.subset(ids))


def test_far_views_beyond_k_change_nothing_and_near_ones_do():
    torch.manual_seed(1)
    cameras: Cameras = orbit_cameras(8, 16)  # 45 degrees apart around the origin; the target sits by view 0
    views = SourceViews(torch.rand(8, 16, 16, 3), cameras)
    near = [0, 1, 7]  # views 1 and 7 flank view 0: every sample of the centre ray is nearest to these three
    alone = render_centre(subset(views, near), sample_views=3)
    assert torch.allclose(render_centre(views, sample_views=3), alone, atol=1e-5)
    assert not torch.allclose(render_centre(views, sample_views=0), alone, atol=1e-3)


@pytest.mark.parametrize("field, value", [("colour_prior_views", 6), ("sample_views", 12)])
def test_the_inference_settings_round_trip_and_default_to_off(field, value):
    config = dataclasses.replace(ModelConfig(), **{field: value})
    assert getattr(config_from_json(ModelConfig, config_to_json(config)), field) == value
    with pytest.raises(ValueError):
        dataclasses.replace(ModelConfig(), **{field: -1})
    assert getattr(ModelConfig(), field) == 0  # older checkpoints keep their behaviour
