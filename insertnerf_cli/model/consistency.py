"""Photo-consistency: how much the reference views agree on a sample's colour, and compositing weights sharpened
toward the samples where they agree (a plane-sweep stereo cue).

A surface point looks alike from nearby views; a point in empty space projects onto unrelated pixels. The
generator learns this from synthetic scenes only, and on real photos its weights spread over depths where the views
disagree (a doubled edge, a pale haze: docs/research-log.md, Training data and the generator). The cue below needs
no training: the variance of the reference colours over the views nearest in angle, turned into a per-ray
distribution over the samples and multiplied into the learned weights, keeping each ray's opacity.
"""
from __future__ import annotations

import torch
from torch import Tensor

from insertnerf_cli.model.aggregate import weighted_moments


def colour_variance(colours: Tensor, mask: Tensor, prior: Tensor, samples: int) -> Tensor:
    """[R, S] summed RGB variance of the reference colours of each sample under view weights ``prior``: the
    lumigraph prior of the K views nearest in angle (aggregate.angular_prior: the K-th nearest and farther views get
    no weight, so K = 4 takes the variance over the 3 nearest, the nearest weighing most).

    Args:
        colours: [V, 3, P] reference colours at the samples' projections (zero where a view cannot see).
        mask: [V, 1, P] 1 where the view sees the sample.
        prior: [V, 1, P] view weights summing to 1 over the views that see the sample.
        samples: S, samples per ray (P = R * S).
    A sample fewer than two views see has no evidence either way: it gets its ray's largest variance, so it is
    never preferred, and a ray no two views see keeps its weights.
    """
    with torch.no_grad():
        _, var = weighted_moments(colours, prior)  # [1, 3, P]
        cost = var.sum(dim=1)[0].reshape(-1, samples)  # [R, S]
        lonely = (mask.sum(dim=0)[0] < 2).reshape(-1, samples)  # [R, S]
        worst = torch.where(lonely, torch.zeros_like(cost), cost).amax(dim=-1, keepdim=True)  # [R, 1]
        return torch.where(lonely, worst, cost)


def sharpen(weights: Tensor, cost: Tensor, temperature: float) -> Tensor:
    """Compositing weights [R, S] times exp(-cost / temperature) per ray, rescaled to each ray's opacity.

    ``cost`` [R, S] is shifted by its minimum per ray, so the factor is 1 at the most consistent sample and the
    product cannot underflow to nothing there; a ray whose product still vanishes (all its weight where the views
    disagree completely) keeps its learned weights. The factor carries no gradient: it steers where the learned
    weights sit, it is not learned.
    """
    with torch.no_grad():
        factor = torch.exp(-(cost - cost.amin(dim=-1, keepdim=True)) / temperature)  # [R, S] in (0, 1]
    product = weights * factor
    mass, kept = weights.sum(dim=-1, keepdim=True), product.sum(dim=-1, keepdim=True)
    vanished = kept <= 1e-6 * mass
    return torch.where(vanished, weights, product * (mass / kept.clamp(min=1e-30)))
