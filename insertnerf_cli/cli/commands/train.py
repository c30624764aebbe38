"""`insertnerf train`: train the generator on a folder of scenes."""
from __future__ import annotations

from pathlib import Path

import click

from insertnerf_cli.cli.commands.common import device_option, overwrite_option, resolve_device, user_errors
from insertnerf_cli.training import TrainConfig, TrainResult, train as train_generator
from insertnerf_cli.training.config import read_model_config, saved_train_config, with_overrides
from insertnerf_cli.training.run_dir import RunFiles


@click.command("train")
@click.argument("dataset_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "run_dir", type=click.Path(path_type=Path), required=True,
              help="Run folder: metrics.jsonl, splits.json, checkpoints/last.pt, best.pt and config.json.")
@click.option("--steps", type=int, help="Total optimisation steps of the run.  [default: 50000]")
@click.option("--minutes", type=float, help="Stop and save after this much training wall time in total.")
@device_option
@click.option("--resume", is_flag=True, help="Continue the run in --out exactly where its last checkpoint stopped.")
@click.option("--conditioning", type=click.Choice(["hyper", "concat"]),
              help="HyperNet modules (InsertNeRF) or plain feature concatenation (the ablation).  [default: hyper]")
@click.option("--rays", type=int, help="Rays per step, over all its scenes.  [default: 512]")
@click.option("--views", type=int, help="Source views per scene of a step (the most, with --views-min).  "
              "[default: 8]")
@click.option("--views-min", type=int, help="Draw each step's number of source views from VIEWS_MIN..--views, so "
              "the model serves any count `render --views` asks for (e.g. --views-min 4 --views 16).")
@click.option("--guide-prior/--no-guide-prior", default=None, help="Place the fine samples as render does with a "
              "scene's SfM points, from a sparse depth prior simulated on synth's exact depth (scenes without depth "
              "files train as before).  [default: no-guide-prior]")
@click.option("--guide-from", type=click.Choice(["depth", "features"]), help="The guide's prior: each surface ray's "
              "own depth spoilt at random, or the source views' corners lifted by that depth and splatted into the "
              "target as render splats SfM points.  [default: depth]")
@click.option("--batch-scenes", type=int, help="Scenes per step, each with --rays / B rays and its own source "
              "views (one batch).  [default: 1 on CPU, 4 on CUDA]")
@click.option("--data-budget-mb", type=int, help="Keep the decoded training images on the training device up to "
              "this size; a larger set is read from disk each step (slower).  [default: 4096]")
@click.option("--resolution", type=int, help="Long side of the training images in pixels.  [default: 160]")
@click.option("--precision", type=click.Choice(["fp32", "bf16"]), help="Arithmetic of the training step: bf16 "
              "runs it under bf16 autocast (validation stays float32): 1.18-1.26x rays/s per single-thread process "
              "on an AVX512-BF16 CPU; a CPU without bf16 instructions may be slower (bench/train_throughput.py "
              "measures it).  [default: fp32]")
@click.option("--compile/--no-compile", default=None, help="Compile the per-scale aggregation with "
              "torch.compile: 1.1-1.3x rays/s on a 2-core CPU, after up to a minute of compiling; needs a C++ "
              "compiler.  [default: no-compile]")
@click.option("--lr", type=float, help="Initial learning rate of the NeRF part (the encoder's is twice it by "
              "default).  [default: 5e-4]")
@click.option("--val-every", type=int, help="Steps between validations.  [default: 500]")
@click.option("--ckpt-every", type=int, help="Steps between checkpoints.  [default: 1000]")
@click.option("--log-every", type=int, help="Steps averaged into one line of metrics.jsonl.  [default: 10]")
@click.option("--seed", type=int, help="Seed of the initialisation, the data draws and the hold-out split.")
@click.option("--model-config", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="JSON file of ModelConfig fields (or a run's checkpoints/config.json).")
@click.option("--init", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Start from this checkpoint's weights instead of random ones (e.g. the bundled generator for a "
              "model config that changes only the sample counts: those weights are resampled).")
@overwrite_option
@user_errors
def train(dataset_dir: Path, run_dir: Path, device: str, resume: bool, overwrite: bool,
          model_config: Path | None, **flags: object) -> None:
    """Train the InsertNeRF generator on the scenes in DATASET_DIR (scene folders in any format `render`
    reads, mixed; a few are held out for validation). Ctrl-C saves a checkpoint; --resume continues.

    \b
    Examples:
      insertnerf synth data/ --scenes 200
      insertnerf train data/ --out runs/hyper --minutes 30
      insertnerf train data/ --out runs/hyper --resume --steps 100000
      torchrun --no-python --nproc_per_node 4 insertnerf train data/ --out runs/big --device cuda

    \b
    Fastest on a CPU: one single-thread process per core (here 2), for a CPU with bf16 units:
      OMP_NUM_THREADS=1 torchrun --no-python --nproc_per_node 2 insertnerf train data/
          --out runs/cpu --device cpu --compile --precision bf16
    """
    torch_device = resolve_device(device)
    base = saved_train_config(RunFiles(run_dir).last) if resume else TrainConfig()
    model_fields = {"conditioning": flags.pop("conditioning"), "num_views": flags.pop("views")}
    if flags["lr"] is not None:
        flags["lr_encoder"] = 2.0 * flags["lr"]  # keep GNT's ratio between the extractor and the rest
    if model_config is not None:
        base = with_overrides(base, {}, {"model": read_model_config(model_config)})
    if flags["init"] is not None:
        flags["init"] = str(flags["init"].resolve())
    if flags["guide_from"] is not None and flags["guide_prior"] is None:
        flags["guide_prior"] = True  # naming the guide's prior asks for the guide
    config = with_overrides(base, model_fields, {name.replace("-", "_"): value for name, value in flags.items()})
    result = train_generator(dataset_dir, run_dir, config, torch_device, resume=resume, overwrite=overwrite)
    if result.main_process:
        click.echo(result_summary(result))
    if result.stopped == "interrupted":
        if result.main_process:
            click.echo(f"Continue with: insertnerf train {dataset_dir} --out {run_dir} --resume", err=True)
        raise SystemExit(130)


def result_summary(result: TrainResult) -> str:
    """One line: why it stopped, steps, time, throughput, validation PSNR and the checkpoint."""
    val = "n/a" if result.val_psnr is None else f"{result.val_psnr:.2f} dB"
    speed = "" if result.rays_per_s is None else f", {result.rays_per_s:,.0f} rays/s"
    return (f"{result.stopped}: step {result.step} ({result.steps_this_session} this session, "
            f"{result.elapsed_s / 60:.1f} min in total{speed}); validation PSNR {val}; checkpoint "
            f"{Path(result.checkpoint).resolve()}")
