"""Probe: inference-only variants of the photo-consistency cue, swept before it became ModelConfig's
``consistency_temperature_*`` fields (issue 27, round 11; docs/model-card.md). The same weights; InsertNeRF's
coarse weights and shading are patched in this process only.

A variant is alpha:tau:k[:blur[:mode[:blend[:fine]]]]: the coarse weights become (1 - alpha) * learned +
alpha * softmax_S(-cost / tau) ("mix") or learned * softmax_S(-cost / tau) ** alpha ("product"), the cost of a
sample being the variance of the reference colours (box-blurred over 2 blur + 1 pixels; a negative blur -r: each
image locally contrast-normalised over 2r + 1 pixels, (I - mean) / (std + LCN_FLOOR) per channel, a gain- and
offset-free cost like NCC's, whose tau is on another scale) over its k views nearest in
angle; ``fine`` > 0 multiplies the fine weights by softmax_S(-cost / tau) ** fine; ``blend`` scales the learned
share of the network's own colour (0: the reference colour alone). Scored with eval's library call on the dev
captures like bench/views_ab.py (the library's version: export copies with scripts/export_weights.py
--consistency-temperature-coarse/--consistency-temperature-fine and score them with bench/views_ab.py).

    OMP_NUM_THREADS=2 python3 bench/pc_probe.py --variants 0:0.05:4,0.0001:0.01:4:1:product:1:1 --views 3,10 --max-views 3
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.checkpoint import bundled_checkpoint, export_weights  # noqa: E402
from insertnerf_cli.compositing import composite, composite_weights  # noqa: E402
from insertnerf_cli.evaluate import EvalConfig, run_eval  # noqa: E402
from insertnerf_cli.model.aggregate import angular_prior, weighted_moments  # noqa: E402
from insertnerf_cli.model.insertnerf import InsertNeRF  # noqa: E402
from insertnerf_cli.model.projection import project_samples  # noqa: E402
from insertnerf_cli.sampling import stratified_samples  # noqa: E402

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
_learned = InsertNeRF.coarse_weights
LCN_FLOOR = 0.02  # colour std below which a patch counts as flat (noise is not amplified into texture)
SETTINGS = {"alpha": 0.0, "tau": 0.05, "k": 4, "blur": 1, "mode": "mix", "blend": 1.0, "fine": 0.0}
_shade = InsertNeRF.shade


def shade(self, head, seen, rays, samples, reference, backdrop, temperature=0.0):
    """As InsertNeRF.shade with the learned blend (the share of the network's own colour) scaled by SETTINGS."""
    if SETTINGS["blend"] == 1.0 and SETTINGS["fine"] == 0.0:
        return _shade(self, head, seen, rays, samples, reference, backdrop, temperature)
    field = head(seen.points, rays.directions, seen.conds)
    blend = field.blend * SETTINGS["blend"]
    colour = blend * field.colour + (1.0 - blend) * reference
    weights = composite_weights(field.density, samples.edges, rays.directions.norm(dim=-1))
    if SETTINGS["fine"] > 0.0:
        photo = torch.softmax(-photo_cost(self, SETTINGS["_encoded"], rays, samples) / SETTINGS["tau"], dim=-1)
        mass = weights.sum(-1, keepdim=True)
        sharpened = weights * photo ** SETTINGS["fine"]
        weights = sharpened / sharpened.sum(-1, keepdim=True).clamp(min=1e-12) * mass
    return composite(weights, colour, samples.t, backdrop)


def blurred(encoded, radius: int):
    if radius == 0:
        return encoded.images
    key = ("blur", radius, id(encoded.images))
    cache = SETTINGS.setdefault("_cache", {})
    if key not in cache:
        cache.clear()
        cache[key] = box(encoded.images, radius) if radius > 0 else normalised(encoded.images, -radius)
    return cache[key]


def box(images, radius: int):
    return F.avg_pool2d(images, 2 * radius + 1, stride=1, padding=radius, count_include_pad=False)


def normalised(images, radius: int):
    """Local contrast normalisation per channel over (2 radius + 1)^2 pixels: a view's gain and offset gone."""
    mean = box(images, radius)
    std = (box(images * images, radius) - mean * mean).clamp(min=0.0).sqrt()
    return (images - mean) / (std + LCN_FLOOR)


def photo_cost(self, encoded, rays, samples):
    """[R, S] colour variance over the k views nearest in angle, per coarse sample."""
    points = samples.points(rays)
    rays_n, samples_n = points.shape[:2]
    images = blurred(encoded, SETTINGS["blur"])
    view = type(encoded)(features=(images,), images=images, projection=encoded.projection, centers=encoded.centers,
                         height=encoded.height, width=encoded.width)
    seen = project_samples(view, points, rays.directions)
    weights = angular_prior(seen.ray_diff, seen.mask, SETTINGS["k"])  # [V, 1, P]
    _, var = weighted_moments(seen.features[0], weights)  # [1, 3, P]
    cost = var.sum(dim=1)[0]  # [P]
    # Fewer than two views see it: no evidence, the worst cost.
    lonely = seen.mask.sum(dim=0)[0] < 2
    cost = torch.where(lonely, cost.max().clamp(min=1.0), cost)
    return cost.reshape(rays_n, samples_n)


def coarse_weights(self, encoded, rays):
    SETTINGS["_encoded"] = encoded
    samples, learned = _learned(self, encoded, rays)
    alpha = SETTINGS["alpha"]
    if alpha == 0.0:
        return samples, learned
    rays = rays.to(device=self.background.device, dtype=self.background.dtype)
    cost = photo_cost(self, encoded, rays, samples)
    photo = torch.softmax(-cost / SETTINGS["tau"], dim=-1)
    if SETTINGS["mode"] == "product":
        mixed = learned * photo ** alpha
        return samples, mixed / mixed.sum(-1, keepdim=True).clamp(min=1e-8) * learned.sum(-1, keepdim=True)
    return samples, (1 - alpha) * learned + alpha * photo * learned.sum(-1, keepdim=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=None)
    parser.add_argument("--captures", default="beer,room,flower,mold_gold_cape")
    parser.add_argument("--views", default="3,10")
    parser.add_argument("--max-views", type=int, default=3)
    parser.add_argument("--variants", default="0:0.05:4", help="alpha:tau:k[:blur[:mode[:blend[:fine]]]],...")
    args = parser.parse_args()
    InsertNeRF.coarse_weights = coarse_weights
    InsertNeRF.shade = shade
    counts = tuple(int(v) for v in args.views.split(","))
    # The probe's own cue replaces the config's: score a copy without it (the bundled weights carry it).
    scratch = tempfile.TemporaryDirectory(prefix="pc_probe_")
    checkpoint = export_weights(args.checkpoint or bundled_checkpoint(), Path(scratch.name) / "plain.pt",
                                consistency_temperature_coarse=0.0, consistency_temperature_fine=0.0)
    for variant in args.variants.split(","):
        parts = variant.split(":")
        SETTINGS.update(alpha=float(parts[0]), tau=float(parts[1]), k=int(parts[2]),
                        blur=int(parts[3]) if len(parts) > 3 else 1, mode=parts[4] if len(parts) > 4 else "mix",
                        blend=float(parts[5]) if len(parts) > 5 else 1.0,
                        fine=float(parts[6]) if len(parts) > 6 else 0.0)
        for capture in args.captures.split(","):
            run = run_eval(REALDATA / capture, EvalConfig(views=counts, checkpoint=checkpoint,
                                                          max_views=args.max_views))
            cells = [f"{r.psnr:.2f} / {r.ssim:.3f}" for r in run.reports]
            print(f"{variant} | {capture} | " + " | ".join(cells), flush=True)


if __name__ == "__main__":
    main()
