"""`insertnerf poses`: camera poses for a folder of photos, with COLMAP (pycolmap) on the CPU."""
from __future__ import annotations

from pathlib import Path

import click

from insertnerf_cli.cli.commands.common import overwrite_option, user_errors


def default_out(images_dir: Path) -> Path:
    """The sibling folder ``<IMAGES_DIR>_scene``."""
    images_dir = images_dir.resolve()
    return images_dir.with_name(f"{images_dir.name}_scene")


@click.command("poses")
@click.argument("images_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(path_type=Path),
              help="Scene folder to write. Default: a sibling folder named <IMAGES_DIR>_scene.")
@click.option("--matcher", type=click.Choice(["auto", "exhaustive", "sequential", "chain"]), default="auto",
              show_default=True, help="Image pairs to match: every pair, or neighbours in name order (video "
              "frames; chain: only the 5 next images, for symmetric objects); auto = exhaustive up to 100 images, "
              "sequential above (and every pair after all, up to 300 images, when that places under 80% of them), "
              "mapped again as a chain when the poses jump between images next to each other in name order.")
@click.option("--max-image-size", type=click.IntRange(min=100), default=1600, show_default=True,
              help="Long side (pixels) the feature extractor sees; larger needs more memory and time.")
@click.option("--allow-inconsistent", is_flag=True,
              help="Keep poses that fail the two-view consistency check (only warn).")
@overwrite_option
@click.option("--verbose", is_flag=True, help="Show COLMAP's own log.")
@user_errors
def poses(images_dir: Path, out_dir: Path | None, matcher: str, max_image_size: int, allow_inconsistent: bool,
          overwrite: bool, verbose: bool) -> None:
    """Estimate camera poses for the photos in IMAGES_DIR and write a scene folder that `render` and other
    NeRF tools (nerfstudio, instant-ngp) read: undistorted images/, transforms.json, colmap/sparse/0,
    sparse.ply and cameras.ply (a camera preview).

    \b
    Example:
      insertnerf poses photos/ --out scene/
    """
    # pycolmap loads lazily: importing it installs glog's signal handlers in every process (synth workers too).
    from insertnerf_cli.poses.estimate import PosesOptions, estimate_poses

    options = PosesOptions(matcher=matcher, max_image_size=max_image_size, overwrite=overwrite, verbose=verbose,
                           allow_inconsistent=allow_inconsistent)
    result = estimate_poses(images_dir, out_dir or default_out(images_dir), options,
                            report=lambda line: click.echo(line, err=True))
    click.echo(result.summary())
