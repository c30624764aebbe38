"""Volume compositing against analytic cases and a cumulative-product reference; the chunked image renderer."""
from __future__ import annotations

import pytest
import torch

from insertnerf_cli.cameras.rays import rays_for_image
from insertnerf_cli.model.compositing import composite, composite_weights, median_depth
from insertnerf_cli.rendering.image_renderer import EXACT, render_image
from insertnerf_cli.model.sampling import stratified_samples
from model_fixtures import FAR, NEAR, orbit_cameras, tiny_model_and_views

pytestmark = pytest.mark.usefixtures("one_thread")

R, S = 5, 8
BLACK = torch.zeros(3)
WHITE = torch.ones(3)


def _bins() -> tuple[torch.Tensor, torch.Tensor]:
    edges = torch.linspace(2.0, 6.0, S + 1).expand(R, S + 1)  # [R, S+1]
    return 0.5 * (edges[:, 1:] + edges[:, :-1]), edges


def test_opaque_first_sample_gives_its_colour_and_depth():
    t, edges = _bins()
    density = torch.zeros(R, S)
    density[:, 0] = 1e4
    colour = torch.rand(R, S, 3)
    out = composite(composite_weights(density, edges, torch.ones(R)), colour, t, WHITE)
    torch.testing.assert_close(out.rgb, colour[:, 0])
    torch.testing.assert_close(out.opacity, torch.ones(R))
    torch.testing.assert_close(out.depth, t[:, 0])


def test_opaque_sample_k_gives_depth_t_k():
    t, edges = _bins()
    density = torch.zeros(R, S)
    k = torch.arange(R) + 1
    density[torch.arange(R), k] = 1e4
    out = composite(composite_weights(density, edges, torch.ones(R)), torch.rand(R, S, 3), t, BLACK)
    torch.testing.assert_close(out.depth, t[torch.arange(R), k])


def test_median_depth_of_two_equal_weights_is_their_midpoint_whatever_the_opacity():
    t, _ = _bins()
    for mass in (1.0, 0.3):
        weights = torch.zeros(R, S)
        weights[:, 2:4] = 0.5 * mass
        torch.testing.assert_close(median_depth(weights, t), 0.5 * (t[:, 2] + t[:, 3]))


def test_median_depth_moves_steadily_from_one_sample_to_the_next_as_weight_shifts():
    t = torch.linspace(2.0, 6.0, 41)[None].expand(11, 41)
    weights = torch.zeros(11, 41)
    share = torch.linspace(0.0, 1.0, 11)
    weights[:, 10], weights[:, 11] = 1.0 - share, share
    depth = median_depth(weights, t)
    assert depth[0] == pytest.approx(3.0) and depth[-1] == pytest.approx(3.1)
    assert torch.all(depth[1:] - depth[:-1] >= 0) and torch.all(depth[1:] - depth[:-1] <= 0.1 / 5 + 1e-6)


def test_a_faint_tail_behind_a_surface_moves_the_median_depth_far_less_than_the_mean():
    # 80 % of the weight at t = 3 and 20 % spread over t = 5..6 behind it, as a reflection seen at its virtual depth.
    t = torch.linspace(2.0, 6.0, 41)[None]
    weights = torch.zeros(1, 41)
    weights[0, 10] = 0.8
    weights[0, 30:] = 0.2 / 11
    mean = float((weights * t).sum() / weights.sum())
    assert mean == pytest.approx(3.5, abs=1e-4)
    assert abs(float(median_depth(weights, t)[0]) - 3.0) < 0.05
    assert abs(float(composite(weights, torch.rand(1, 41, 3), t, WHITE).depth[0]) - 3.0) < 0.05  # what render writes


def test_zero_density_gives_background():
    t, edges = _bins()
    for background in (BLACK, WHITE, torch.tensor([0.2, 0.5, 0.9])):
        out = composite(composite_weights(torch.zeros(R, S), edges, torch.ones(R)), torch.rand(R, S, 3), t,
                        background)
        torch.testing.assert_close(out.rgb, background.expand(R, 3))
        assert torch.all(out.opacity == 0)
        assert torch.all((out.depth >= 2.0) & (out.depth <= 6.0))


def test_weights_are_nonnegative_sum_to_at_most_one_and_match_cumprod_reference():
    torch.manual_seed(0)
    t, edges = _bins()
    density = torch.rand(R, S) * torch.logspace(-2, 2, R)[:, None]
    scale = torch.rand(R) + 0.5
    w = composite_weights(density, edges, scale)
    assert torch.all(w >= 0) and torch.all(w.sum(-1) <= 1 + 1e-6)
    alpha = 1 - torch.exp(-density * (edges[:, 1:] - edges[:, :-1]) * scale[:, None])
    trans = torch.cumprod(torch.cat([torch.ones(R, 1), 1 - alpha[:, :-1]], dim=-1), dim=-1)
    torch.testing.assert_close(w, alpha * trans)


def test_ray_scale_is_a_density_scale():
    """Longer direction vectors cover more world distance per unit t: same as a denser medium."""
    t, edges = _bins()
    density = torch.rand(R, S)
    torch.testing.assert_close(composite_weights(density, edges, torch.full((R,), 2.0)),
                               composite_weights(2 * density, edges, torch.ones(R)))


def test_render_image_is_chunk_invariant_and_matches_the_forward():
    model, encoded, camera = tiny_model_and_views()
    with torch.no_grad():
        direct = model(encoded, rays_for_image(camera, torch.tensor([NEAR]), torch.tensor([FAR])), train=False).fine
    small = render_image(model, encoded, camera, NEAR, FAR, chunk=7, shortcuts=EXACT)
    big = render_image(model, encoded, camera, NEAR, FAR, chunk=10_000, shortcuts=EXACT)
    assert small.rgb.shape == (8, 8, 3) and small.depth.shape == (8, 8) and small.opacity.shape == (8, 8)
    torch.testing.assert_close(small.rgb, big.rgb)
    torch.testing.assert_close(small.depth, big.depth)
    torch.testing.assert_close(big.rgb, direct.rgb.reshape(8, 8, 3).clamp(0, 1))
    torch.testing.assert_close(big.opacity, direct.opacity.reshape(8, 8))
    assert torch.all((big.depth >= NEAR - 1e-4) & (big.depth <= FAR + 1e-4))
    assert not big.rgb.requires_grad


@pytest.mark.slow
def test_render_image_on_worker_threads_matches_one_thread_and_restores_the_thread_count():
    model, encoded, camera = tiny_model_and_views()
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        serial = render_image(model, encoded, camera, NEAR, FAR, chunk=5)
        torch.set_num_threads(2)
        threaded = render_image(model, encoded, camera, NEAR, FAR, chunk=5)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    torch.testing.assert_close(threaded.rgb, serial.rgb)
    torch.testing.assert_close(threaded.depth, serial.depth)


def test_stratified_samples_use_their_bins_for_compositing():
    """Bins evenly split [near, far]: a uniform density integrates to 1 - exp(-sigma * length)."""
    rays = rays_for_image(orbit_cameras(1, 4), torch.tensor([NEAR]), torch.tensor([FAR]))
    samples = stratified_samples(rays, 32, jitter=True)
    w = composite_weights(torch.full(samples.t.shape, 0.3), samples.edges, rays.directions.norm(dim=-1))
    length = (rays.far - rays.near) * rays.directions.norm(dim=-1)
    torch.testing.assert_close(w.sum(-1), 1 - torch.exp(-0.3 * length))
