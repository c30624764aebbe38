"""Speed, memory and size of the generator on this machine.

Prints, for each conditioning mode: the parameter count of each part, the training-step throughput in rays/s
(forward + backward + Adam, encoder included), seconds per rendered frame, and peak resident memory.
Medians of --repeats runs after one warm-up. Example:

    python bench/model_speed.py --threads 2 --repeats 5
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import resource
import statistics
import time

import torch

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.config import ModelConfig, config_from_json
from insertnerf_cli.model import InsertNeRF, SourceViews
from insertnerf_cli.model.hypernet import count_parameters
from insertnerf_cli.rendering.camera_paths import look_at
from insertnerf_cli.cameras.rays import rays_for_image
from insertnerf_cli.rendering.image_renderer import render_image

RADIUS, NEAR, FAR = 3.0, 1.5, 4.5


def orbit(n: int, size: int, phase: float = 0.0) -> Cameras:
    angles = phase + 2 * math.pi * torch.arange(n, dtype=torch.float64) / n
    eyes = torch.stack([RADIUS * angles.cos(), RADIUS * angles.sin(), torch.ones_like(angles)], -1)
    c2w = look_at(eyes, torch.zeros(3, dtype=torch.float64), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    K = intrinsics(size, size, size / 2, size / 2).expand(n, 3, 3).clone()
    return Cameras(K, c2w, size, size).to(dtype=torch.float32)


def part_sizes(model: InsertNeRF) -> dict[str, int]:
    """Parameter count of each part (the fine head only when it is separate)."""
    heads = {"coarse": model.coarse_head}
    if model.fine_head is not model.coarse_head:
        heads["fine"] = model.fine_head
    sizes = {"encoder U-Net": count_parameters(model.encoder) - count_parameters(model.encoder.decoder),
             "backbone decoder (loss only)": count_parameters(model.encoder.decoder)}
    for scale, agg in zip(("1/8", "1/4", "1/2"), model.aggregators):
        sizes[f"aggregation {scale}"] = count_parameters(agg)
    for name, head in heads.items():
        sizes[f"{name} head: geometry conditioners"] = count_parameters(head.conditioners)
        sizes[f"{name} head: original NeRF layers + density"] = (count_parameters(head.originals)
                                                                 + count_parameters(head.density))
        sizes[f"{name} head: appearance"] = (count_parameters(head.appearance_in) + count_parameters(head.appearance)
                                             + count_parameters(head.colour))
    sizes["total"] = count_parameters(model)
    return sizes


class Timer:
    """Wall and CPU seconds (all threads of this process) of a block; CPU time is what a shared machine's
    contention does not inflate, so both are reported."""

    def __enter__(self) -> "Timer":
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall, self.cpu = time.perf_counter() - self.wall, time.process_time() - self.cpu


def medians(timers: list[Timer]) -> tuple[float, float]:
    return statistics.median(t.wall for t in timers), statistics.median(t.cpu for t in timers)


def time_train(model: InsertNeRF, args: argparse.Namespace) -> tuple[float, float]:
    """Median (wall, CPU) seconds of one training step (encode + both passes + losses + backward + Adam)."""
    cams = orbit(args.views + 1, args.resolution)
    images = torch.rand(args.views + 1, args.resolution, args.resolution, 3)
    views = SourceViews(images[1:], cams.subset(list(range(1, args.views + 1))))
    rays = rays_for_image(cams.subset([0]), torch.tensor([NEAR]), torch.tensor([FAR]))
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-4)
    model.train()
    timers = []
    for _ in range(args.repeats + 1):
        pick = torch.randint(0, len(rays), (args.rays,))
        with Timer() as timer:
            encoded = model.encode(views)
            out = model(encoded, rays[pick], train=True)
            loss = model.losses(out, images[0].reshape(-1, 3)[pick], encoded).total
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        timers.append(timer)
    return medians(timers[1:])


def time_render(model: InsertNeRF, args: argparse.Namespace) -> tuple[float, float]:
    """Median (wall, CPU) seconds to encode the reference views and render one frame."""
    views = SourceViews(torch.rand(args.render_views, args.frame, args.frame, 3), orbit(args.render_views, args.frame))
    camera = orbit(1, args.frame, phase=0.3)
    model.eval()
    timers = []
    for _ in range(args.render_repeats + 1):
        with Timer() as timer:
            with torch.inference_mode():
                encoded = model.encode(views)
            render_image(model, encoded, camera, NEAR, FAR, chunk=args.chunk)
        timers.append(timer)
    return medians(timers[1:])


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20  # ru_maxrss is in KiB on Linux


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--rays", type=int, default=512, help="rays per training step")
    parser.add_argument("--views", type=int, default=8, help="source views per training step")
    parser.add_argument("--resolution", type=int, default=160, help="training image side (pixels)")
    parser.add_argument("--frame", type=int, default=200, help="rendered frame side (pixels)")
    parser.add_argument("--render-views", type=int, default=10)
    parser.add_argument("--chunk", type=int, default=128)
    parser.add_argument("--modes", default="hyper,concat")
    parser.add_argument("--render-repeats", type=int, default=1)
    parser.add_argument("--skip-render", action="store_true")
    parser.add_argument("--skip-train", action="store_true")
    parser.add_argument("--config", default="{}", help="JSON overrides of ModelConfig fields")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    base = config_from_json(ModelConfig, json.loads(args.config))
    print(f"threads {args.threads}, {args.rays} rays x ({base.samples_coarse}+{base.samples_fine}) samples, "
          f"{args.views} source views at {args.resolution}px; frame {args.frame}px from {args.render_views} views")
    for mode in args.modes.split(","):
        torch.manual_seed(0)
        model = InsertNeRF(dataclasses.replace(base, conditioning=mode))
        print(f"\n== conditioning={mode}")
        for name, size in part_sizes(model).items():
            print(f"  {name:45s} {size:>9,d}")
        if not args.skip_render:
            wall, cpu = time_render(model, args)
            print(f"  render: {wall:.2f} s wall ({cpu:.2f} s CPU) per {args.frame}x{args.frame} frame, "
                  f"peak RSS {peak_rss_gb():.2f} GB")
        if not args.skip_train:
            wall, cpu = time_train(model, args)
            print(f"  train: {wall:.3f} s wall ({cpu:.3f} s CPU) per step = {args.rays / wall:.0f} rays/s wall, "
                  f"{args.rays / cpu:.0f} rays per CPU-second, peak RSS {peak_rss_gb():.2f} GB")
    print(f"\nload average while measuring: {os.getloadavg()[0]:.1f} (other processes share the cores)")


if __name__ == "__main__":
    main()
