"""`insertnerf synth`: render procedural multi-view scenes (the generator's training data)."""
from __future__ import annotations

import os
from pathlib import Path

import click

from insertnerf_cli.cli.commands.common import overwrite_option, user_errors


@click.command("synth")
@click.argument("out_dir", type=click.Path(file_okay=False, dir_okay=True, path_type=Path))
@click.option("--scenes", type=click.IntRange(min=1), required=True, help="Number of scenes to render.")
@click.option("--views", type=click.IntRange(min=2), default=50, show_default=True,
              help="Views per scene, test views included.")
@click.option("--test-views", type=click.IntRange(min=0),
              help="Views per scene held out in transforms_test.json.  [default: views // 8, at least 1]")
@click.option("--resolution", type=click.IntRange(min=8), default=200, show_default=True,
              help="Long side of the images in pixels (the aspect ratio is drawn per scene).")
@click.option("--square", is_flag=True, help="Square images only (like NeRF-Synthetic).")
@click.option("--fov", "fov", metavar="LOW:HIGH", callback=lambda ctx, param, value: _fov_range(value),
              help="Field of view of the images' long side in degrees, drawn per scene from this range, e.g. 20:35 "
                   "for zoomed or telephoto captures.  [default: 35:75]")
@click.option("--layout", type=click.Choice(["object", "forward", "360", "handheld", "mixed"]), default="mixed",
              show_default=True, help="Camera layout; mixed draws one of the four per scene.")
@click.option("--supports/--no-supports", default=False, show_default=True,
              help="360 scenes: the subject stands on a plinth, a pedestal or a table (often plain white) instead "
                   "of the floor, as a sculpture on its stand.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Dataset seed: the same seed and options give byte-identical images.")
@click.option("--workers", type=click.IntRange(min=1), default=os.cpu_count() or 1, show_default=True,
              help="Parallel worker processes.")
@click.option("--noise/--no-noise", default=False, show_default=True, help="Sensor noise (shot + read).")
@click.option("--jitter/--no-jitter", default=False, show_default=True,
              help="Exposure and white-balance jitter between views.")
@click.option("--jpeg/--no-jpeg", default=False, show_default=True, help="JPEG compression artefacts.")
@click.option("--photo/--no-photo", default=False, show_default=True,
              help="Look like phone photos: per-view exposure (up to +-0.5 stop) and white balance, slight "
                   "defocus or motion blur, vignetting, plus sensor noise and JPEG.")
@overwrite_option
@user_errors
def synth(out_dir: Path, workers: int, overwrite: bool, square: bool, noise: bool, jitter: bool, jpeg: bool,
          photo: bool, fov: tuple[float, float] | None, **options: object) -> None:
    """Render SCENES procedural scenes with exact cameras and depth into OUT_DIR (Blender format).

    Re-running the same command resumes an interrupted run; finished scenes are kept.

    \b
    Example:
      insertnerf synth data/synth --scenes 1000 --views 50 --resolution 200 --layout mixed
    """
    from insertnerf_cli.synth import CaptureOptions, SynthOptions, build_dataset

    if options["test_views"] is None:
        options["test_views"] = max(1, int(options["views"]) // 8)  # type: ignore[call-overload]
    config = SynthOptions(**options, aspects=(1.0,) if square else SynthOptions().aspects,  # type: ignore[arg-type]
                          capture=CaptureOptions(noise=noise, jitter=jitter, jpeg=jpeg, photo=photo),
                          fov=fov or SynthOptions().fov)
    run = build_dataset(out_dir, config, workers=workers, overwrite=overwrite)
    speed = f" at {run.views_per_second:.1f} views/s" if run.rendered else ""
    kept = f" ({run.skipped} already there)" if run.skipped else ""
    click.echo(f"Rendered {run.rendered} scenes{speed}{kept} into {out_dir} (listed in manifest.json). "
               f"Train on them with: insertnerf train {out_dir} --out runs/synth")


def _fov_range(text: str | None) -> tuple[float, float] | None:
    """``LOW:HIGH`` (or one number, a fixed field of view) as degrees; the range's own limits are SynthOptions'."""
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(":"))
    except ValueError:
        values = ()
    if len(values) not in (1, 2):
        raise click.BadParameter(f"expected LOW:HIGH in degrees, e.g. 20:35; got {text!r}")
    return (values[0], values[-1])
