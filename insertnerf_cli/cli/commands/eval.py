"""`insertnerf eval`: PSNR and SSIM of held-out views rendered from the other views, at one or several
reference-view counts."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from insertnerf_cli.cli.commands.common import device_option, overwrite_option, resolve_device, user_errors
from insertnerf_cli.cli.commands.weights import chosen_weights, model_options
from insertnerf_cli.config import DEFAULT_VIEWS
from insertnerf_cli.exporters.records import EvalConfig, EvalRun
from insertnerf_cli.pipelines.evaluate import run_eval


class ViewCounts(click.ParamType):
    """A reference-view count or a comma-separated list of them ("10", "3,6,10,16"), each >= 1."""

    name = "N[,N...]"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, tuple):
            return value
        parts = [p.strip() for p in str(value).split(",")]
        try:
            counts = tuple(int(p) for p in parts)
        except ValueError:
            self.fail(f"{value!r} is not a count or a comma-separated list of counts (e.g. 3,6,10,16).", param, ctx)
        if min(counts) < 1:
            self.fail(f"{value!r}: every count must be at least 1.", param, ctx)
        return counts


_views_option = click.option(
    "--views", type=ViewCounts(), default=str(DEFAULT_VIEWS), show_default=True,
    help="Reference views per held-out view (the nearest ones), or a comma-separated list of counts, e.g. "
         "3,6,10,16: each count is scored on the same held-out views in one run and printed as a table.")


def _table(run: EvalRun) -> list[str]:
    """Per held-out view a row of PSNR / SSIM per count, then the means."""
    width = max([len("held-out view")] + [len(v.name) for v in run.reports[0].views])
    head = f"{'held-out view':<{width}}" + "".join(f" | {f'{r.reference_views} views':>15}" for r in run.reports)
    lines = [head, "-" * len(head)]
    for row, view in enumerate(run.reports[0].views):
        lines.append(f"{view.name:<{width}}" + "".join(f" | {r.views[row].psnr:6.2f} / {r.views[row].ssim:.4f}"
                                                       for r in run.reports))
    lines.append(f"{'mean':<{width}}" + "".join(f" | {r.psnr:6.2f} / {r.ssim:.4f}" for r in run.reports))
    return lines


@click.command("eval")
@click.argument("scene_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the scores to this JSON file (keys psnr, ssim, views; for a list of --views counts: "
                   "reference_views and by_count, one report per count).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Write side-by-side images (render | truth | error) and report.html to this folder.")
@click.option("--max-views", type=click.IntRange(min=1),
              help="Score at most this many held-out views, evenly spread (a quicker preview: the others stay out "
                   "of the references, so each score is the one the full run gives).")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Processes that score held-out views side by side (the scores are the same with any number, up "
                   "to float rounding).  [default: on a CPU one per core, each with at least 3 views; on a GPU 1]")
@model_options(views_option=_views_option)
@device_option
@overwrite_option
@user_errors
def eval_command(scene_dir: Path, json_path: Path | None, out_dir: Path | None, max_views: int | None,
                 workers: int | None, views: tuple[int, ...], resolution: int, model: str, checkpoint: Path | None,
                 backbone: str | None, chunk: int,
                 exact: bool, sfm_depth: bool, points_cache: Path | None, device: str, overwrite: bool) -> None:
    """Score novel-view quality on SCENE_DIR: render each held-out view (the test split, else every 8th view)
    from its nearest other views and compare it with the photo.

    \b
    Examples:
      insertnerf eval scene/ --json scores.json --out side_by_side/
      insertnerf eval scene/ --views 3,6,10,16      # how the score changes with the number of views
    """
    config = EvalConfig(views=views[0] if len(views) == 1 else views, resolution=resolution or None,
                        checkpoint=chosen_weights(model, checkpoint, backbone), device=str(resolve_device(device)),
                        chunk=chunk, exact=exact, sfm_depth=sfm_depth, out_dir=out_dir, json_path=json_path,
                        max_views=max_views, overwrite=overwrite, points_cache=points_cache, workers=workers)
    run = run_eval(scene_dir, config)
    written = [f"{what} in {path.resolve()}" for what, path in
               (("report", json_path), ("side-by-sides and report.html", out_dir)) if path is not None]
    first = run.reports[0]
    if len(run.reports) == 1:
        for view in first.views:
            click.echo(f"{view.name}: PSNR {view.psnr:.2f} dB, SSIM {view.ssim:.4f}")
        click.echo(f"mean over {len(first.views)} held-out views ({first.width}x{first.height}): "
                   f"PSNR {first.psnr:.2f} dB, SSIM {first.ssim:.4f}" + "".join(f"; {w}" for w in written))
        return
    click.echo(f"PSNR (dB) / SSIM of {len(first.views)} held-out views ({first.width}x{first.height}) by the "
               "number of reference views:")
    for line in _table(run):
        click.echo(line)
    if written:
        click.echo("; ".join(written))
