"""Issue 27: the angular (unstructured-lumigraph) prior on the reference colour's view weights."""
from __future__ import annotations

import dataclasses

import pytest
import torch

from insertnerf_cli.model import InsertNeRF, SourceViews
from insertnerf_cli.model.aggregate import angular_prior, reweigh
from insertnerf_cli.cameras.rays import rays_from_pixels
from insertnerf_cli.model.sampling import RaySamples
from model_fixtures import TINY, flat_views, orbit_cameras

pytestmark = pytest.mark.usefixtures("one_thread")


def ray_diff_at(angles: list[float]) -> torch.Tensor:
    """[V, 4, 1] ray_diff of views whose rays through one sample make ``angles`` (radians) with the query ray."""
    query = torch.tensor([0.0, 0.0, 1.0])
    a = torch.tensor(angles, dtype=torch.float32)
    refs = torch.stack([torch.sin(a), torch.zeros_like(a), torch.cos(a)], dim=-1)  # [V, 3] unit vectors
    return torch.cat([refs - query, (refs @ query)[:, None]], dim=1)[:, :, None]


def test_the_k_nearest_views_in_angle_share_the_weight_as_in_the_lumigraph():
    angles = [0.3, 0.1, 0.4, 0.2]
    weights = angular_prior(ray_diff_at(angles), torch.ones(4, 1, 1), views=3)[:, 0, 0]
    kth = 0.3  # the third smallest angle: it and every wider view get nothing
    expected = torch.tensor([max(0.0, 1 - a / kth) / a for a in angles])
    assert torch.allclose(weights, expected / expected.sum(), atol=1e-5)
    assert weights[0] == 0.0 and weights[2] == 0.0 and weights[1] > weights[3] > 0.0


def test_views_that_miss_the_sample_neither_count_nor_weigh():
    mask = torch.tensor([1.0, 0.0, 1.0, 1.0])[:, None, None]
    weights = angular_prior(ray_diff_at([0.3, 0.1, 0.4, 0.2]), mask, views=2)[:, 0, 0]
    # Without the hidden view (0.1), the two nearest are 0.2 and 0.3: only 0.2 keeps weight.
    assert torch.allclose(weights, torch.tensor([0.0, 0.0, 0.0, 1.0]))
    assert torch.all(angular_prior(ray_diff_at([0.1, 0.2]), torch.zeros(2, 1, 1), views=2) == 0.0)


def test_with_fewer_views_than_k_every_view_keeps_a_share_and_a_view_on_the_ray_takes_all():
    weights = angular_prior(ray_diff_at([0.1, 0.2, 0.4]), torch.ones(3, 1, 1), views=6)[:, 0, 0]
    widest = 1.5 * 0.4
    expected = torch.tensor([(1 - a / widest) / a for a in (0.1, 0.2, 0.4)])
    assert torch.allclose(weights, expected / expected.sum(), atol=1e-5)
    on_ray = angular_prior(ray_diff_at([0.0, 0.05, 0.1]), torch.ones(3, 1, 1), views=6)[:, 0, 0]
    assert on_ray[0] > 0.9999


def test_reweigh_multiplies_and_renormalises_over_views():
    learned = torch.tensor([0.5, 0.25, 0.25])[:, None, None]
    prior = torch.tensor([0.0, 0.5, 0.5])[:, None, None]
    assert torch.allclose(reweigh(learned, prior)[:, 0, 0], torch.tensor([0.0, 0.5, 0.5]))
    assert torch.all(reweigh(learned, torch.zeros_like(prior)) == 0.0)


def reference_colour_at_origin(views: SourceViews, prior_views: int) -> torch.Tensor:
    """The reference colour [3] at the scene's centre, seen along the centre ray of a camera near view 0."""
    torch.manual_seed(0)
    model = InsertNeRF(dataclasses.replace(TINY, colour_prior_views=prior_views)).eval()
    target = orbit_cameras(1, 16, phase=0.2)
    rays = rays_from_pixels(target, torch.tensor([[[8.0, 8.0]]]), torch.tensor([1.0]), torch.tensor([6.0]))
    t = target.centers.norm(dim=-1)[:, None]  # [1, 1]: the orbit looks at the origin
    with torch.no_grad():
        seen = model.observe(model.encode(views), rays, RaySamples(t, torch.cat([t - 0.01, t + 0.01], dim=-1)))
    return seen.reference_colour()[0, 0]


def test_more_views_do_not_pull_the_colour_away_from_the_nearest_view():
    red, blue = (0.9, 0.1, 0.1), (0.1, 0.1, 0.9)
    for count in (6, 12):
        views = flat_views([red] + [blue] * (count - 1))
        # K = 2: only the nearest view in angle (view 0, 0.2 rad from the target) colours the sample.
        assert torch.allclose(reference_colour_at_origin(views, 2), torch.tensor(red), atol=1e-5)
        # The learned weights alone blend in the farther (blue) views.
        assert reference_colour_at_origin(views, 0)[2] > 0.15

