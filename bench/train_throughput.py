"""Training throughput of `insertnerf train` on this machine: rays/s and peak memory (RSS).

    python3 bench/train_throughput.py                        # default ModelConfig: 64+64 samples, 8 views
    python3 bench/train_throughput.py --conditioning concat  # the concatenation ablation
    python3 bench/train_throughput.py --dataset data/ --steps 40 --threads 2
    python3 bench/train_throughput.py --batch-scenes 2       # 2 scenes per step, 256 rays each
    python3 bench/train_throughput.py --precision bf16 --compile
    python3 bench/train_throughput.py --model-config examples/fast-prior-model.json --device cuda --rays 16384
    torchrun --nproc_per_node 2 bench/train_throughput.py --threads 1 --compile   # DDP: one process per core

It runs the real training loop (scene draws on the device, the decoded training set, nearest-view pool, encode,
both passes, losses, backward, Adam) through ``insertnerf_cli.training.train`` and reads the per-step throughput back from
metrics.jsonl, skipping warm-up steps. Without --dataset it writes 3 posed scenes of 24 views (Blender format,
random smooth colours: the content does not change the cost) at the training resolution; --scenes more when
--batch-scenes needs them (a step's scenes are distinct training scenes; one is held out). Under torchrun every
rank writes the same seeded scenes into its own temporary folder, trains its share under DDP (--rays per rank,
as `insertnerf train` under torchrun), and rank 0 prints the throughput of all ranks together.
"""
from __future__ import annotations

import argparse
import json
import math
import resource
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.cameras.camera import Cameras, intrinsics  # noqa: E402
from insertnerf_cli.config import ModelConfig  # noqa: E402
from insertnerf_cli.model import InsertNeRF  # noqa: E402
from insertnerf_cli.rendering.camera_paths import look_at  # noqa: E402
from insertnerf_cli.scenes import write_blender_transforms  # noqa: E402
from insertnerf_cli.training import TrainConfig, train  # noqa: E402
from insertnerf_cli.training.config import read_model_config  # noqa: E402

NEVER = 10 ** 9  # no validation or periodic checkpoint inside the measured steps


def write_dataset(root: Path, size: int, scenes: int, views: int) -> None:
    """``scenes`` Blender-format scenes of ``views`` cameras on an orbit (radius 4, 30 deg up), 60 deg FOV."""
    rng = np.random.default_rng(0)
    focal = 0.5 * size / math.tan(math.radians(30.0))
    for s in range(scenes):
        angles = torch.arange(views, dtype=torch.float64) * (2 * math.pi / views)
        eyes = torch.stack([4 * torch.cos(angles), 4 * torch.sin(angles), torch.full_like(angles, 2.0)], dim=-1)
        c2w = look_at(eyes, torch.zeros(3, dtype=torch.float64), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
        cameras = Cameras(intrinsics(focal, focal, size / 2, size / 2).expand(views, 3, 3).clone(), c2w, size, size)
        folder = root / f"scene_{s:03d}"
        (folder / "train").mkdir(parents=True)
        names = [f"train/{i:03d}" for i in range(views)]
        for name in names:
            noise = rng.uniform(0, 255, size=(8, 8, 3)).astype(np.uint8)
            cv2.imwrite(str(folder / f"{name}.png"), cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC))
        write_blender_transforms(folder / "transforms_train.json", cameras, names, near=2.0, far=6.0,
                                 extra={"layout": "object"})


def parameter_counts(config: ModelConfig) -> dict[str, int]:
    model = InsertNeRF(config)
    counts: dict[str, int] = {}
    for name, param in model.named_parameters():  # shared modules are listed once
        part = name.split(".")[0]
        counts[part] = counts.get(part, 0) + param.numel()
    counts["total"] = sum(counts.values())
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, help="a dataset folder (default: write a small one)")
    parser.add_argument("--steps", type=int, default=30, help="measured steps")
    parser.add_argument("--warmup", type=int, default=5, help="steps before measuring")
    parser.add_argument("--rays", type=int, default=TrainConfig.rays)
    parser.add_argument("--resolution", type=int, default=TrainConfig.resolution)
    parser.add_argument("--conditioning", choices=["hyper", "concat"], default="hyper")
    parser.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--batch-scenes", type=int, help="scenes per step (default: the device's default)")
    parser.add_argument("--data-budget-mb", type=int, default=TrainConfig.data_budget_mb,
                        help="0 reads the training views from disk each step (the streamed path)")
    parser.add_argument("--scenes", type=int, default=3, help="scenes of the written dataset")
    parser.add_argument("--precision", choices=["fp32", "bf16"], default="fp32")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--compile", action="store_true", help="torch.compile the step (compiles in the warm-up)")
    parser.add_argument("--model-config", type=Path, help="JSON of ModelConfig fields, as `train --model-config` "
                        "(e.g. examples/fast-prior-model.json); --conditioning is then ignored")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    model = read_model_config(args.model_config) if args.model_config else ModelConfig(conditioning=args.conditioning)
    config = TrainConfig(model=model, steps=args.warmup + args.steps, rays=args.rays, resolution=args.resolution,
                         val_every=NEVER, ckpt_every=NEVER, log_every=1, batch_scenes=args.batch_scenes,
                         data_budget_mb=args.data_budget_mb, precision=args.precision, compile=args.compile)
    with tempfile.TemporaryDirectory() as tmp:
        dataset = args.dataset or Path(tmp) / "data"
        if args.dataset is None:
            write_dataset(dataset, args.resolution, scenes=args.scenes, views=24)
        start = time.monotonic()
        result = train(dataset, Path(tmp) / "run", config, torch.device(args.device))
        wall = time.monotonic() - start
        if not result.main_process:
            return  # only rank 0 writes the run folder
        lines = [json.loads(line) for line in (Path(tmp) / "run" / "metrics.jsonl").read_text().splitlines()]
    world = result.processes
    measured = [m for m in lines if m["split"] == "train" and m["step"] > args.warmup]
    seconds = sum(config.rays * world / m["rays_per_s"] for m in measured)  # rays_per_s counts every rank
    rays_per_s = config.rays * world * len(measured) / seconds
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # ru_maxrss is in KiB on Linux
    print(f"config: {args.model_config or args.conditioning}, {model.samples_coarse}+{model.samples_fine} samples, "
          f"{model.num_views} source views, {config.rays} rays/step over {args.batch_scenes or 'default'} "
          f"scene(s), {args.resolution} px, {args.precision}{', compiled' if args.compile else ''}, "
          f"{torch.get_num_threads()} torch threads" + (f" x {world} DDP processes" if world > 1 else ""))
    print(f"parameters: {parameter_counts(model)}")
    print(f"throughput: {rays_per_s:,.0f} rays/s ({seconds / len(measured):.3f} s/step over {len(measured)} steps "
          f"after {args.warmup} warm-up; whole run {wall:.1f} s)")
    print(f"peak memory (RSS): {peak_mb:,.0f} MiB")
    if torch.device(args.device).type == "cuda":  # utilisation: run `nvidia-smi dmon -s u` beside it
        print(f"peak GPU memory: {torch.cuda.max_memory_allocated() / 2 ** 20:,.0f} MiB")


if __name__ == "__main__":
    main()
