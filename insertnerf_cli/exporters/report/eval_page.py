"""`eval`'s report.html: the mean scores per reference-view count (with a chart of PSNR against the count when
there are several), the settings, and per held-out view its scores and its render | truth | error side-by-side."""
from __future__ import annotations

import math

from insertnerf_cli.config import config_to_json
from insertnerf_cli.exporters.eval_outputs import ERROR_VIS_MAX, side_by_side_name
from insertnerf_cli.exporters.records import EvalReport, EvalRun
from insertnerf_cli.exporters.report.html import duration, esc, link, options_table, page, settings_table, table
from insertnerf_cli.exporters.report.svg import line_chart


def _db(x: float) -> str:
    return f"{x:.2f}" if math.isfinite(x) else "inf"


def _settings(run: EvalRun) -> list[tuple[str, object]]:
    c, first = run.config, run.reports[0]
    return [("scene", first.scene.resolve()), ("held-out views", len(first.views)),
            ("reference views", ", ".join(str(r.reference_views) for r in run.reports)),
            ("size", f"{first.width} x {first.height} px"), ("weights", run.checkpoint.name),
            ("shortcuts", "off (--exact)" if c.exact else "on"), ("device", c.device),
            ("whole command", duration(run.wall_s))]


def _means(run: EvalRun) -> str:
    rows = [(esc(r.reference_views), _db(r.psnr), f"{r.ssim:.4f}") for r in run.reports]
    return table(("reference views", "PSNR (dB)", "SSIM"), rows, numeric=(0, 1, 2))


def _views(report: EvalReport, several: bool) -> str:
    rows = []
    for v in report.views:
        image = link(side_by_side_name(v.index, report.reference_views, several))
        rows.append((esc(v.name), _db(v.psnr), f"{v.ssim:.4f}", esc(", ".join(map(str, v.references))),
                     f'<a href="{image}"><img class="thumb" loading="lazy" alt="{esc(v.name)}" src="{image}"></a>'))
    return table(("held-out view", "PSNR (dB)", "SSIM", "references", "render | truth | error"), rows,
                 numeric=(1, 2))


def eval_page(run: EvalRun) -> str:
    """The whole report.html."""
    several = len(run.reports) > 1
    body = f"<h2>Mean over the held-out views</h2>{_means(run)}"
    if several:
        chart = line_chart([r.reference_views for r in run.reports], [r.psnr for r in run.reports],
                           "reference views", "PSNR (dB)")
        body += f"<h2>PSNR against the number of reference views</h2>{chart}"
    body += f"<h2>Settings</h2>{settings_table(_settings(run))}"
    body += f"<h2>Render options</h2>{options_table(config_to_json(run.config.options))}"
    for report in run.reports:
        body += (f"<h2>Each held-out view, {report.reference_views} reference views</h2>"
                 f"{_views(report, several)}")
    body += (f'<p class="sub">Error: mean absolute colour difference per pixel, turbo colours from 0 (blue) to '
             f"{ERROR_VIS_MAX:g} and above (red).</p>")
    best = max(run.reports, key=lambda r: r.psnr)
    return page(f"insertnerf eval: {run.reports[0].scene.resolve().name}",
                f"{len(best.views)} held-out views; best mean PSNR {_db(best.psnr)} dB at {best.reference_views} "
                "reference views", body)
