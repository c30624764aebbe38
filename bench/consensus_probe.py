"""Probe: reference colours weighed by agreement with the views' consensus, against occluders and shadows that some
references hold and the target does not (issue 27, round 15; docs/model-card.md).

Per sample, a mean-shift mode of the reference colours over the views that see it (started from their plain mean,
or from the lumigraph prior of the 5 views nearest in angle), ITERS steps with a Gaussian kernel of width SIGMA; a
view's colour weight is then multiplied by exp(-|c_v - mode|^2 / (2 SIGMA^2)). ``cue`` 1 also weighs the
photo-consistency cue's variance so. InsertNeRF.observe is patched in this process only (the shipped weights).

    OMP_NUM_THREADS=1 python3 bench/consensus_probe.py --variants 0,0.1,0.2,0.1:3:1,0.1:3:0:prior --captures beer \
        --views 3,10 --per-view

A variant is sigma[:iters[:cue[:start]]], start "uniform" (default) or "prior"; sigma 0 = the shipped model.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch
from torch import Tensor

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.model.aggregate import angular_prior, reweigh  # noqa: E402
from insertnerf_cli.model.consistency import colour_variance  # noqa: E402
from insertnerf_cli.model.insertnerf import InsertNeRF  # noqa: E402
from insertnerf_cli.model.projection import project_samples, ray_angle  # noqa: E402
from insertnerf_cli.model.types import SampleFeatures  # noqa: E402
from view_set_probe import add_eval_arguments, score_variants  # noqa: E402

START_PRIOR_VIEWS = 6  # the lumigraph K of the "prior" start (5 views), as the shipped colour prior
SETTINGS = {"sigma": 0.0, "iters": 3, "cue": 0, "start": "uniform"}


def consensus(colours: Tensor, mask: Tensor, start: Tensor) -> Tensor:
    """[V, 1, P] weight of each view's colour [V, 3, P] by its distance to the mode, from view weights ``start``."""
    weights = start * mask
    width = 2.0 * SETTINGS["sigma"] ** 2
    for _ in range(SETTINGS["iters"]):
        mode = (weights * colours).sum(0, keepdim=True) / weights.sum(0, keepdim=True).clamp(min=1e-12)
        weights = mask * torch.exp(-((colours - mode) ** 2).sum(1, keepdim=True) / width)
    return weights


def observe(self, encoded, rays, samples, colour=True, variance=False):
    """InsertNeRF.observe with the consensus weights multiplied into the colour prior (and the cue's, cue 1)."""
    points = samples.points(rays)
    rays_n, samples_n = points.shape[:2]
    seen = project_samples(encoded, points, rays.directions)
    if self.config.sample_views:
        seen = seen.nearest_in_angle(self.config.sample_views)
    angle = ray_angle(seen.ray_diff)
    agree = None
    if SETTINGS["sigma"] > 0:
        with torch.no_grad():
            start = seen.mask if SETTINGS["start"] == "uniform" else angular_prior(
                seen.ray_diff, seen.mask, START_PRIOR_VIEWS, angle)
            agree = consensus(seen.colours, seen.mask, start)
    cost = None
    if variance:
        weights = angular_prior(seen.ray_diff, seen.mask, self.config.consistency_views, angle)
        if agree is not None and SETTINGS["cue"]:
            weights = reweigh(weights, agree)
        cost = colour_variance(seen.colours, seen.mask, weights, samples_n)
    inputs = [*seen.features[:-1], torch.cat([seen.features[-1], seen.colours], dim=1)]
    descriptors, dynamics = zip(*(agg(f, seen.mask, seen.ray_diff) for agg, f in zip(self.aggregators, inputs)))
    dynamic = torch.stack(dynamics).mean(dim=0)
    if colour and self.config.colour_prior_views:
        dynamic = reweigh(dynamic, angular_prior(seen.ray_diff, seen.mask, self.config.colour_prior_views, angle))
        if agree is not None:
            dynamic = reweigh(dynamic, agree)
    return SampleFeatures(points=points, conds=tuple(d.reshape(rays_n, samples_n, -1) for d in descriptors),
                          dynamic=dynamic, colours=seen.colours, colour_variance=cost)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", default="0", help="sigma[:iters[:cue[:start]]], comma-separated")
    add_eval_arguments(parser)
    parser.add_argument("--per-view", action="store_true", help="also print each held-out view's PSNR")
    args = parser.parse_args()
    InsertNeRF.observe = observe
    score_variants(args, args.variants, set_variant, args.per_view)


def set_variant(variant: str) -> None:
    parts = variant.split(":")
    SETTINGS.update(sigma=float(parts[0]), iters=int(parts[1]) if len(parts) > 1 else 3,
                    cue=int(parts[2]) if len(parts) > 2 else 0, start=parts[3] if len(parts) > 3 else "uniform")


if __name__ == "__main__":
    main()
