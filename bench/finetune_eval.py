"""`insertnerf eval` PSNR/SSIM before and after fine-tuning (issue 13's "must show").

    python3 bench/finetune_eval.py /work/shared/realdata/beer /work/shared/realdata/mold_gold_cape --work /tmp/ft
    python3 bench/finetune_eval.py SCENE --minutes 2 --snapshots "" --max-views 5 --rays 128   # a quick probe
    python3 bench/finetune_eval.py SCENE --minutes 5 --snapshots 2 --device cuda               # on a GPU

Per scene: one fine-tune of --minutes that also saves snapshot checkpoints when its optimisation time first
passes each of --snapshots minutes (the learning rate is constant, so a snapshot at 2 minutes is what a 2-minute
run gives), then `eval` (the library behind the command: 10 nearest views, 256 px, every held-out view unless
--max-views) on the base weights and on every checkpoint. Prints a table and writes WORK/results.json, with the
machine's load average before and after each fine-tune and the steps done per minute.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.model.checkpoint import bundled_checkpoint, load_model, save_checkpoint  # noqa: E402
from insertnerf_cli.cli.commands.common import resolve_device  # noqa: E402
from insertnerf_cli.errors import UserError  # noqa: E402
from insertnerf_cli.finetune import FinetuneConfig, Progress, finetune  # noqa: E402
from insertnerf_cli.metrics import psnr  # noqa: E402
from insertnerf_cli.finetune.data import finetune_scene  # noqa: E402
from insertnerf_cli.config import DEFAULT_RESOLUTION, DEFAULT_VIEWS  # noqa: E402
from insertnerf_cli.exporters.records import EvalConfig  # noqa: E402
from insertnerf_cli.pipelines.evaluate import evaluate_scene  # noqa: E402
from insertnerf_cli.training.data import ImageCache, ViewDraw, make_batch  # noqa: E402
from insertnerf_cli.scenes.views import nearest_views  # noqa: E402


def snapshot_hook(marks: list[float], path_for) -> callable:
    """A step hook that saves the model the first time the optimisation time passes each mark (minutes)."""
    pending = sorted(marks)

    def hook(progress: Progress) -> None:
        while pending and progress.elapsed_s >= 60.0 * pending[0]:
            minutes = pending.pop(0)
            save_checkpoint(path_for(minutes), progress.model, progress.model_config)
            print(f"snapshot at {minutes:g} min: step {progress.step}", file=sys.stderr)
    return hook


@torch.no_grad()
def quick_score(scene_dir: Path, checkpoint: Path | None, pixels: int, device: torch.device) -> dict:
    """Mean PSNR over eval's held-out views, each rendered from its 10 nearest usable views as eval does, but on
    ``pixels`` fixed random pixels per view instead of the whole image (a cheap probe for choosing settings)."""
    scene = finetune_scene(scene_dir, DEFAULT_RESOLUTION)
    model = load_model(checkpoint or bundled_checkpoint(), device)[0]
    cache, rng, psnrs = ImageCache(1 << 30), np.random.default_rng(123), []
    usable = list(scene.train_ids)
    for target in scene.test_ids:
        near = nearest_views(scene.cameras.c2w[target], scene.cameras.c2w[usable], DEFAULT_VIEWS, scene.method)
        chosen = torch.from_numpy(rng.integers(0, scene.cameras.height * scene.cameras.width, size=pixels))
        batch = make_batch(scene, cache, ViewDraw(0, target, tuple(usable[i] for i in near), chosen)).to(device)
        encoded = model.encode(batch.views)
        rgb = torch.cat([model.render(encoded, batch.rays[i:i + 256]).rgb for i in range(0, pixels, 256)])
        psnrs.append(psnr(rgb, batch.target_rgb))
    return {"psnr": float(np.mean(psnrs)), "ssim": float("nan"), "views": len(psnrs)}


def score(scene: Path, checkpoint: Path | None, args: argparse.Namespace) -> dict:
    if args.quick:
        return quick_score(scene, checkpoint, args.quick, args.torch_device)
    config = EvalConfig(checkpoint=checkpoint, max_views=args.max_views, device=args.torch_device.type)
    report = evaluate_scene(scene, config)
    return {"psnr": report.psnr, "ssim": report.ssim, "views": len(report.views)}


def fine_tune(scene: Path, args: argparse.Namespace, marks: list[float], path_for) -> dict:
    """One run of --minutes with snapshots at ``marks``; its record (steps at each mark, speed, load)."""
    config = FinetuneConfig(minutes=args.minutes, rays=args.rays, lr=args.lr, train_encoder=args.train_encoder,
                            lr_encoder=args.lr, seed=args.seed, sfm_depth=args.sfm_depth,
                            colour_scale=args.colour_scale)
    load_before = os.getloadavg()
    steps_at: dict[float, int] = {}
    hook = snapshot_hook(marks, path_for)

    def on_step(progress: Progress) -> None:
        for m in marks:
            if m not in steps_at and progress.elapsed_s >= 60.0 * m:
                steps_at[m] = progress.step
        hook(progress)

    result = finetune(scene, path_for(args.minutes), config, args.torch_device, base=args.base, overwrite=True,
                      on_step=on_step)
    return {"steps_at": {str(m): s for m, s in {**steps_at, args.minutes: result.steps}.items()},
            "steps_per_minute": result.steps_per_minute, "load_before": load_before, "load_after": os.getloadavg(),
            "config": {k: str(v) for k, v in vars(args).items()}}


def run_scene(scene: Path, args: argparse.Namespace, work: Path) -> list[dict]:
    marks = [float(m) for m in args.snapshots.split(",") if m.strip()]
    name = f"{scene.name}_{args.tag}" if args.tag else scene.name
    path_for = lambda minutes: work / f"{name}_{minutes:g}min.pt"  # noqa: E731
    record_path = work / f"{name}_run.json"
    if not args.score_only:
        record_path.write_text(json.dumps(fine_tune(scene, args, marks, path_for), indent=2) + "\n")
    record = json.loads(record_path.read_text()) if record_path.is_file() else {"steps_at": {}}
    wanted = [0.0, *marks, args.minutes] if args.score is None else [float(m) for m in args.score.split(",")]
    rows = []
    for minutes in [m for m in wanted if m or not args.skip_before]:
        checkpoint = args.base if minutes == 0 else path_for(minutes)
        rows.append({"scene": scene.name, "minutes": minutes, "steps": record["steps_at"].get(str(minutes), 0),
                     "metric": f"pixels {args.quick}" if args.quick else "eval", **score(scene, checkpoint, args),
                     **{k: record.get(k) for k in ("steps_per_minute", "load_before", "load_after")}})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenes", nargs="+", type=Path)
    parser.add_argument("--work", type=Path, default=Path("/tmp/finetune_eval"))
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--snapshots", default="2,5", help="comma-separated minutes ('' for none)")
    parser.add_argument("--base", type=Path, help="weights to start from (default: the bundled default "
                        "generator), e.g. insertnerf_cli/weights/insertnerf.pt (--model full)")
    parser.add_argument("--rays", type=int, default=FinetuneConfig.rays)
    parser.add_argument("--lr", type=float, default=FinetuneConfig.lr)
    parser.add_argument("--train-encoder", action="store_true")
    parser.add_argument("--max-views", type=int, help="evaluate at most this many held-out views")
    parser.add_argument("--quick", type=int, help="score on this many random pixels per held-out view, not eval")
    parser.add_argument("--score-only", action="store_true", help="only score the checkpoints already in WORK")
    parser.add_argument("--skip-before", action="store_true", help="do not score the base weights")
    parser.add_argument("--score", help="comma-separated minutes to score (0 = the base weights) [default: all]")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 on a shared 2-core machine)")
    parser.add_argument("--device", default="cpu", choices=["auto", "cpu", "cuda"],
                        help="where to fine-tune and score (the command's --device)")
    parser.add_argument("--seed", type=int, default=FinetuneConfig.seed, help="seed of the draws and the jitter")
    parser.add_argument("--no-sfm-depth", dest="sfm_depth", action="store_false",
                        help="fine-tune with the fine samples placed by the coarse pass alone (before round 20)")
    parser.add_argument("--colour-scale", type=float, default=FinetuneConfig.colour_scale,
                        help="sources' colours from the photos at up to this many times the size (round 23)")
    parser.add_argument("--tag", default="", help="suffix of the checkpoint names")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    try:
        args.torch_device = resolve_device(args.device)
    except UserError as error:
        parser.error(str(error))
    args.work.mkdir(parents=True, exist_ok=True)
    rows = [row for scene in args.scenes for row in run_scene(scene, args, args.work)]
    print(f"{'scene':<16}{'minutes':>8}{'steps':>7}{'PSNR':>8}{'dPSNR':>7}{'SSIM':>8}  steps/min  load before->after"
          "  metric")
    base = {r["scene"]: r["psnr"] for r in rows if r["minutes"] == 0}
    for r in rows:
        delta = f"{r['psnr'] - base[r['scene']]:+.2f}" if r["scene"] in base else "n/a"
        print(f"{r['scene']:<16}{r['minutes']:>8g}{r['steps'] or 0:>7}{r['psnr']:>8.2f}{delta:>7}{r['ssim']:>8.4f}"
              f"  {r['steps_per_minute'] or 0:9.1f}  {(r['load_before'] or [0])[0]:.2f}->{(r['load_after'] or [0])[0]:.2f}"
              f"  {r['metric']}")
    out = args.work / f"results{'_' + args.tag if args.tag else ''}{'_quick' if args.quick else ''}.json"
    old = json.loads(out.read_text()) if out.is_file() else []
    out.write_text(json.dumps(old + rows, indent=2, default=str) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
