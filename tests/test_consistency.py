"""Issue 27: the photo-consistency cue (model/consistency.py) that moves compositing weight to where views agree."""
from __future__ import annotations

import dataclasses

import pytest
import torch

from insertnerf_cli.config import ModelConfig
from insertnerf_cli.model import InsertNeRF
from insertnerf_cli.model.aggregate import angular_prior
from insertnerf_cli.model.consistency import colour_variance, sharpen
from insertnerf_cli.model.projection import project_samples
from insertnerf_cli.cameras.rays import rays_from_pixels
from insertnerf_cli.model.sampling import stratified_samples
from model_fixtures import FAR, NEAR, RADIUS, TINY, orbit_cameras, sphere_hit, sphere_views

pytestmark = pytest.mark.usefixtures("one_thread")

SIZE = 32
# Pixels around the image centre of a camera looking at the sphere's centre: their rays hit the sphere's near side.
CENTRE = torch.tensor([[[SIZE / 2 + dx, SIZE / 2 + dy] for dx in (-2.0, 0.0, 2.0) for dy in (-2.0, 0.0, 2.0)]])


def hit_depth(rays) -> torch.Tensor:
    """[R] exact ray parameter of each ray's first hit on the sphere (every ray here hits it)."""
    t = sphere_hit(rays.origins, rays.directions)
    assert torch.all(torch.isfinite(t))
    return t.float()


def centre_rays():
    return rays_from_pixels(orbit_cameras(1, SIZE, phase=0.3), CENTRE, torch.tensor([NEAR]), torch.tensor([FAR]))


def test_the_views_agree_most_at_the_true_surface():
    views = sphere_views(8, SIZE)
    rays = centre_rays()
    samples = stratified_samples(rays, 96, jitter=False)
    encoded = InsertNeRF(TINY).eval().encode(views)
    seen = project_samples(encoded, samples.points(rays), rays.directions)
    prior = angular_prior(seen.ray_diff, seen.mask, views=4)
    cost = colour_variance(seen.colours, seen.mask, prior, samples=96)  # [R, S]
    best = samples.t.gather(1, cost.argmin(dim=1, keepdim=True))[:, 0]
    spacing = (FAR - NEAR) / 96
    # Not every ray: a free-space point whose nearest views all see the plain white background agrees there too
    # (the textureless ambiguity of any stereo cue), so the learned weights stay in charge; most rays find it.
    assert ((best - hit_depth(rays)).abs() <= 3 * spacing).float().mean() >= 0.75
    assert torch.all(cost.amax(dim=1) > 10 * cost.amin(dim=1).clamp(min=1e-8))


def test_a_sample_fewer_than_two_views_see_gets_its_rays_worst_cost():
    colours = torch.tensor([[0.0, 1.0, 0.5], [1.0, 0.0, 0.5]])[:, None, :].expand(2, 3, 3).contiguous()  # [V=2, 3, P=3]
    mask = torch.tensor([[1.0, 1.0, 1.0], [1.0, 1.0, 0.0]])[:, None, :]  # sample 2: one view only
    ray_diff = torch.zeros(2, 4, 3)
    ray_diff[:, 3] = 1.0
    ray_diff[0, 0], ray_diff[1, 0] = 0.05, 0.1  # both views a little off the query ray
    cost = colour_variance(colours * mask, mask, angular_prior(ray_diff, mask, views=3), samples=3)[0]
    assert cost[2] == cost[:2].max() and cost[0] > 0 and cost[1] > 0


def test_sharpen_keeps_each_rays_opacity_and_moves_weight_to_the_consistent_sample():
    weights = torch.tensor([[0.3, 0.3, 0.3], [0.1, 0.2, 0.1], [0.0, 0.0, 0.0]])
    cost = torch.tensor([[0.5, 0.0, 0.5], [0.2, 0.2, 0.2], [0.0, 1.0, 2.0]])
    out = sharpen(weights, cost, temperature=0.01)
    torch.testing.assert_close(out.sum(dim=1), weights.sum(dim=1))
    assert out[0, 1] > 0.899 and out[0, 0] < 1e-6  # all of the ray's opacity at its consistent sample
    torch.testing.assert_close(out[1], weights[1])  # no preference: unchanged
    assert torch.all(out[2] == 0.0)  # an empty ray stays empty
    # A ray whose weight all sits where the views disagree completely keeps its learned weights.
    lost = sharpen(torch.tensor([[0.0, 0.5]]), torch.tensor([[0.0, 10.0]]), temperature=0.01)
    torch.testing.assert_close(lost, torch.tensor([[0.0, 0.5]]))


def test_sharpened_weights_put_the_untrained_depth_at_the_surface():
    views = sphere_views(8, SIZE)
    rays = centre_rays()
    truth = hit_depth(rays)
    depth = {}
    for temperature in (0.0, 0.002):
        torch.manual_seed(0)
        config = dataclasses.replace(TINY, samples_coarse=48, samples_fine=48,
                                     consistency_temperature_coarse=temperature,
                                     consistency_temperature_fine=temperature)
        model = InsertNeRF(config).eval()
        with torch.inference_mode():
            depth[temperature] = model.render(model.encode(views), rays).depth
    error_off = (depth[0.0] - truth).abs().median()
    error_on = (depth[0.002] - truth).abs().median()
    assert error_on < 0.1 * RADIUS / 3 and error_on < 0.5 * error_off


def test_the_config_refuses_negative_temperatures_and_fewer_than_two_views():
    with pytest.raises(ValueError, match="consistency_temperature_fine"):
        ModelConfig(consistency_temperature_fine=-0.01)
    with pytest.raises(ValueError, match="consistency_views"):
        ModelConfig(consistency_views=1)
