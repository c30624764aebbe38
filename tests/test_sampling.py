"""Stratified and importance sampling: order, bounds, bins, and concentration on a peak."""
from __future__ import annotations

import torch

from insertnerf_cli.cameras.rays import Rays
from insertnerf_cli.model.sampling import importance_samples, stratified_samples

R = 6


def _rays() -> Rays:
    near = torch.linspace(0.5, 2.0, R)
    return Rays(torch.zeros(R, 3), torch.randn(R, 3), near, near + torch.linspace(1.0, 5.0, R))


def _check_sorted_within(t: torch.Tensor, edges: torch.Tensor, rays: Rays) -> None:
    eps = 1e-5
    assert torch.all(t[:, 1:] >= t[:, :-1]) and torch.all(edges[:, 1:] >= edges[:, :-1] - eps)
    assert torch.all(t >= rays.near[:, None] - eps) and torch.all(t <= rays.far[:, None] + eps)
    assert torch.all(edges >= rays.near[:, None] - eps) and torch.all(edges <= rays.far[:, None] + eps)
    assert torch.all(edges[:, :-1] <= t + eps) and torch.all(t <= edges[:, 1:] + eps)  # each sample in its bin


def test_stratified_jittered_sorted_in_bounds_one_per_bin():
    torch.manual_seed(0)
    rays = _rays()
    for in_disparity in (False, True):
        s = stratified_samples(rays, 16, jitter=True, in_disparity=in_disparity)
        assert s.t.shape == (R, 16) and s.edges.shape == (R, 17)
        _check_sorted_within(s.t, s.edges, rays)
        torch.testing.assert_close(s.edges[:, 0], rays.near)
        torch.testing.assert_close(s.edges[:, -1], rays.far)


def test_stratified_without_jitter_is_bin_centres_and_with_jitter_varies():
    rays = _rays()
    s = stratified_samples(rays, 8, jitter=False)
    torch.testing.assert_close(s.t, 0.5 * (s.edges[:, 1:] + s.edges[:, :-1]))
    a, b = stratified_samples(rays, 8, jitter=True), stratified_samples(rays, 8, jitter=True)
    assert not torch.equal(a.t, b.t)


def test_disparity_bins_are_even_in_inverse_depth():
    rays = _rays()
    inv = 1.0 / stratified_samples(rays, 8, jitter=False, in_disparity=True).edges
    steps = inv[:, 1:] - inv[:, :-1]
    torch.testing.assert_close(steps, steps[:, :1].expand_as(steps))


def test_importance_samples_concentrate_on_a_peak():
    torch.manual_seed(0)
    rays = _rays()
    coarse = stratified_samples(rays, 32, jitter=False)
    weights = torch.full((R, 32), 1e-4)
    weights[:, 20] = 0.9
    for jitter in (False, True):
        fine = importance_samples(coarse, weights, 64, jitter=jitter, near=rays.near, far=rays.far)
        assert fine.t.shape == (R, 64) and fine.edges.shape == (R, 65)
        _check_sorted_within(fine.t, fine.edges, rays)
        in_peak = (fine.t >= coarse.edges[:, 20:21]) & (fine.t <= coarse.edges[:, 21:22])
        assert in_peak.float().mean() > 0.85


def test_importance_samples_on_empty_rays_spread_evenly():
    rays = _rays()
    coarse = stratified_samples(rays, 16, jitter=False)
    fine = importance_samples(coarse, torch.zeros(R, 16), 16, jitter=False, near=rays.near, far=rays.far)
    torch.testing.assert_close(fine.t, coarse.t, atol=1e-4, rtol=1e-4)


def test_importance_samples_do_not_backpropagate_into_weights():
    rays = _rays()
    coarse = stratified_samples(rays, 8, jitter=True)
    weights = torch.rand(R, 8, requires_grad=True)
    fine = importance_samples(coarse, weights, 8, jitter=True, near=rays.near, far=rays.far)
    assert not fine.t.requires_grad
