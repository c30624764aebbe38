"""Probe: the aggregators' static view weights scaled by the angular prior (issue 27, round 22; room's rim views).

The colour prior (aggregate.angular_prior, K nearest in angle) decides whose colour a sample takes, but the
descriptors the density is read from are the static-weighted mean and variance over every reference:
exp(|s| (cos - 1)) with a learned s is almost flat at the few degrees that separate a forward-facing grid's rays,
so a rim view's far references weigh as much as its near ones there. Here each aggregator's static weights are
multiplied by the angular prior of K views (prior:K) and renormalised; with K or fewer references the prior still
reweighs by angle. Inference only, patched in this process (ScaleAggregator.static_weights).

    OMP_NUM_THREADS=2 python3 bench/static_prior_probe.py --variants off,prior:6,prior:10 --captures room --views 3,10
"""
from __future__ import annotations

import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.model.aggregate import ScaleAggregator, angular_prior, reweigh  # noqa: E402
from view_set_probe import variants_main  # noqa: E402

SETTINGS = {"views": 0}
_static_weights = ScaleAggregator.static_weights
_forward = ScaleAggregator.forward
STATE = threading.local()  # render's chunks run on worker threads


def forward(self: ScaleAggregator, features, mask, ray_diff):
    """The aggregator's forward with its ray_diff kept for static_weights (which is handed only the cosine)."""
    STATE.ray_diff = ray_diff
    try:
        return _forward(self, features, mask, ray_diff)
    finally:
        STATE.ray_diff = None


def static_weights(self: ScaleAggregator, cos, mask):
    weights = _static_weights(self, cos, mask)
    ray_diff = getattr(STATE, "ray_diff", None)
    if not SETTINGS["views"] or ray_diff is None:
        return weights
    return reweigh(weights, angular_prior(ray_diff, mask, SETTINGS["views"]))


def set_variant(variant: str) -> None:
    name, _, value = variant.partition(":")
    SETTINGS["views"] = int(value) if name == "prior" else 0


def main() -> None:
    def patch() -> None:
        ScaleAggregator.forward = forward
        ScaleAggregator.static_weights = static_weights

    variants_main(__doc__, "off,prior:6", set_variant, patch)


if __name__ == "__main__":
    main()
