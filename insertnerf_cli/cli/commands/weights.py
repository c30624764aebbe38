"""The options that choose the generator's weights and how it renders, shared by `render`, `eval` and `finetune`:
--model, --checkpoint, --backbone (chosen_weights turns them into one checkpoint path), --views, --resolution,
--chunk, --exact, --sfm-depth, --points-cache."""
from __future__ import annotations

import functools
from pathlib import Path
from typing import Any, Callable

import click

from insertnerf_cli.config import BACKBONES, DEFAULT_RESOLUTION, DEFAULT_VIEWS
from insertnerf_cli.errors import UserError
from insertnerf_cli.model.checkpoint import (BUNDLED_MODELS, DEFAULT_BACKBONE, DEFAULT_MODEL, bundled_checkpoint,
                                             read_checkpoint)


backbone_option = click.option(
    "--backbone", type=click.Choice(BACKBONES),
    help="Structure of space of the bundled generator: nerf, one field from near to far; nerfpp, NeRF++'s "
    "foreground field inside a sphere around the subject and cameras and a background field out to infinity "
    "(docs/method.md; not yet better on 360-degree captures, docs/model-card.md). With --checkpoint it must match "
    f"the checkpoint's.  [default: {DEFAULT_BACKBONE}]")


def model_options(func: Callable[..., Any] | None = None, *, views_option: Callable | None = None) -> Any:
    """--views, --resolution, --model, --checkpoint, --backbone, --chunk, --exact, --sfm-depth, --points-cache:
    shared by render and eval (eval passes its own --views, which takes a list)."""
    if func is None:
        return functools.partial(model_options, views_option=views_option)
    options = [
        views_option or click.option("--views", type=click.IntRange(min=1), default=DEFAULT_VIEWS, show_default=True,
                                     help="Reference views per rendered image (the nearest ones)."),
        click.option("--resolution", type=click.IntRange(min=0), default=DEFAULT_RESOLUTION, show_default=True,
                     help="Long side of the rendered images in pixels; 0 = the photos' own size. Never upsamples: "
                     "a larger value gives the photos' size."),
        click.option("--model", type=click.Choice(sorted(BUNDLED_MODELS)),
                     help="Which bundled pretrained generator renders: fast takes 32+16 samples per ray, full "
                     f"64+64 (about 2x slower, the same picture quality, smoother depth maps; docs/model-card.md).  "
                     f"[default: {DEFAULT_MODEL}]"),
        click.option("--checkpoint", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                     help="Generator weights from `insertnerf train` or `finetune` instead of a bundled --model."),
        backbone_option,
        click.option("--chunk", type=click.IntRange(min=1),
                     help="Rays per network call; lower it if memory runs out.  [default: 512 on CPU, 4096 on "
                     "CUDA]"),
        click.option("--exact", is_flag=True,
                     help="Give every pixel its own coarse pass and a fine pass (slower). By default the coarse "
                     "pass runs on every 8th pixel, background pixels skip the fine pass, and pixels between "
                     "agreeing neighbours are blended from them (within 0.3 dB)."),
        click.option("--sfm-depth/--no-sfm-depth", default=True, show_default=True,
                     help="Send most fine samples to the depth of the scene's structure-from-motion points seen "
                     "at each pixel, draw a pixel whose reference photos agree better at that depth than at "
                     "the rendered one as their blend there, and leave a photo out of the samples its own points "
                     "show hidden behind a nearer surface (sharper on real photos; docs/model-card.md). The "
                     "points come from the scene's "
                     "COLMAP model (poses from `insertnerf poses` have one); a scene without points gets them "
                     "triangulated at its own poses first (SIFT matched along the epipolar lines, about 40-90 s "
                     "for 30-120 photos on 2 cores)."),
        click.option("--points-cache", type=click.Path(file_okay=False, path_type=Path), metavar="DIR",
                     help="Keep the SfM points triangulated at the scene's poses (when it has none) in DIR, "
                     "outside the scene, so that later runs into other output folders load them instead of "
                     "triangulating again; keyed by the photos, poses and settings, never removed by --overwrite.  "
                     "[default: OUT/points/; eval: with --out only]"),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def chosen_weights(model: str | None, checkpoint: Path | None, backbone: str | None = None) -> Path | None:
    """The --checkpoint (whose backbone must be --backbone's when both are given), else None for the default bundled
    generator, else the bundled file of --model and --backbone."""
    if checkpoint is not None:
        if model is not None:
            raise UserError(f"--model {model} and --checkpoint {checkpoint} both name weights: pass one of them.")
        theirs = read_checkpoint(checkpoint).model_config.backbone if backbone is not None else None
        if theirs != backbone:
            raise UserError(f"{checkpoint} holds a generator of the {theirs} backbone, not --backbone {backbone}: "
                            "drop --backbone, or pass a checkpoint trained with that backbone.")
        return checkpoint
    if model in (None, DEFAULT_MODEL) and backbone in (None, DEFAULT_BACKBONE):
        return None
    return bundled_checkpoint(model or DEFAULT_MODEL, backbone or DEFAULT_BACKBONE)
