"""Probe: `insertnerf train` with transients in some source views (issue 27, round 15).

Round 15 found beer's worst held-out views spoilt by what a group of references holds and the target does not: a
shadow (most likely the photographer's) in five of them, a railing in front of the wall in another five. Here a
share of each step's source views gets one transient that neither the target nor the other views show: a soft
shadow (the view darkened to 35-80 % inside a soft ellipse covering up to ~40 % of each side) or, one time in three,
an opaque blob of one random colour. The network can only lower its loss by not lending those views' colours.
make_step_batch is patched in this process; the rest is the `insertnerf train` command line as given.

    OMP_NUM_THREADS=1 python3 bench/transient_train.py --transient-share 0.3 data/gpu32/mix --init runs/r10-fast.pt \
        --model-config examples/fast-prior-model.json --steps 100000 --minutes 25 --val-every 100000 \
        --ckpt-every 50 --device cpu --rays 512 --batch-scenes 1 --lr 1.5e-4 --seed 0 --out runs/v_transient

Not resumable to the digit (the transients' generator is not in the checkpoint): a probe, not a recipe.
"""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import torch
from torch import Tensor

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli import cli  # noqa: E402
from insertnerf_cli.training import batches  # noqa: E402

SHADOW_DARKNESS = (0.35, 0.8)  # what a shadow leaves of the light
RADIUS = (0.08, 0.4)  # ellipse half-axes, as a share of the image side
SOFTNESS = (0.15, 0.8)  # edge width of a shadow, in units of the normalised radius
OCCLUDER_SHARE = 1 / 3
SETTINGS = {"share": 0.0, "generator": None}
_make_step_batch = batches.make_step_batch


def add_transients(sources: Tensor, generator: torch.Generator, share: float) -> Tensor:
    """Sources [N, H, W, 3] in [0, 1] with a transient in each view drawn at probability ``share`` (a copy)."""
    n, h, w, _ = sources.shape

    def uniform(bounds: tuple[float, float]) -> Tensor:
        return bounds[0] + (bounds[1] - bounds[0]) * torch.rand(n, generator=generator)

    hit = torch.rand(n, generator=generator) < share
    centre_y, centre_x = torch.rand(n, generator=generator) * h, torch.rand(n, generator=generator) * w
    radius_y, radius_x = uniform(RADIUS) * h, uniform(RADIUS) * w
    darkness, softness = uniform(SHADOW_DARKNESS), uniform(SOFTNESS)
    occluder = torch.rand(n, generator=generator) < OCCLUDER_SHARE
    colour = torch.rand(n, 3, generator=generator)
    if not hit.any():
        return sources
    ys = torch.arange(h, dtype=torch.float32)[None, :, None] + 0.5
    xs = torch.arange(w, dtype=torch.float32)[None, None, :] + 0.5
    d2 = ((ys - centre_y[:, None, None]) / radius_y[:, None, None]) ** 2 + \
        ((xs - centre_x[:, None, None]) / radius_x[:, None, None]) ** 2  # [N, H, W]
    edge = torch.where(occluder, torch.full_like(softness, 0.05), softness)[:, None, None]
    alpha = ((1.0 - d2) / edge).clamp(0.0, 1.0) * hit[:, None, None]  # [N, H, W]
    alpha = alpha.to(sources)[..., None]
    shadowed = sources * (1.0 - alpha * (1.0 - darkness.to(sources)[:, None, None, None]))
    covered = sources * (1.0 - alpha) + alpha * colour.to(sources)[:, None, None, :]
    return torch.where(occluder.to(sources.device)[:, None, None, None], covered, shadowed)


def make_step_batch(data, draw, cache):
    """batches.make_step_batch with transients added to the source views."""
    batch = _make_step_batch(data, draw, cache)
    views = batch.views
    images = add_transients(views.images.cpu(), SETTINGS["generator"], SETTINGS["share"]).to(views.images)
    return replace(batch, views=replace(views, images=images))


def main() -> None:
    args = sys.argv[1:]
    if "--transient-share" not in args:
        sys.exit("usage: transient_train.py --transient-share P TRAIN-ARGS...")
    at = args.index("--transient-share")
    share = float(args[at + 1])
    del args[at:at + 2]
    seed = int(args[args.index("--seed") + 1]) if "--seed" in args else 0
    SETTINGS.update(share=share, generator=torch.Generator().manual_seed(10_000 + seed))
    batches.make_step_batch = make_step_batch
    print(f"transient_train: a shadow or blob in {share:.0%} of the source views (seed {seed})", file=sys.stderr,
          flush=True)
    sys.argv = ["insertnerf", "train", *args]
    cli.main()


if __name__ == "__main__":
    main()
