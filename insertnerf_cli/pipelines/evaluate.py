"""The library behind `insertnerf eval` (no click here): held-out views (the test split, else every 8th)
rendered from the nearest of the other views -> PSNR/SSIM; for a list of reference-view counts, every count on the
same held-out views in one run (each reference view encoded once per held-out view, whatever the counts).
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from insertnerf_cli.errors import UserError
from insertnerf_cli.exporters.eval_outputs import (
    OWNER,
    REPORT_HTML,
    check_eval_outputs,
    prepare_side_by_sides,
    side_by_side,
    side_by_side_name,
)
from insertnerf_cli.exporters.outputs import write_png
from insertnerf_cli.exporters.records import EvalConfig, EvalReport, EvalRun, ViewScore
from insertnerf_cli.exporters.report.eval_page import eval_page
from insertnerf_cli.files.atomic import write_bytes, write_json
from insertnerf_cli.files.lock import lock_output, releases_output_locks
from insertnerf_cli.metrics import SSIM_WINDOW, psnr, ssim
from insertnerf_cli.pipelines.inputs import points_cache
from insertnerf_cli.pipelines.processes import RendererSpec, run_side_by_side, worker_count
from insertnerf_cli.rendering.view_renderer import ViewRenderer, checkpoint_path, load_model
from insertnerf_cli.scenes import load_scene, normalize_scene, walk_warning
from insertnerf_cli.scenes.views import evenly_spread, held_out_views
from insertnerf_cli.sfm.triangulate import with_points


def evaluate_scene(scene_dir: str | Path, config: EvalConfig) -> EvalReport:
    """The report of a one-count eval (see :func:`run_eval`)."""
    if len(config.counts) != 1:
        raise ValueError("evaluate_scene scores one reference-view count; use run_eval for several")
    return run_eval(scene_dir, config).reports[0]


@releases_output_locks
def run_eval(scene_dir: str | Path, config: EvalConfig) -> EvalRun:
    """Render each held-out view from its nearest non-held-out views at every count of ``config.counts``, score
    it against the photo, and write the side-by-sides, report.html and JSON report that ``config`` asks for."""
    started = time.perf_counter()
    counts = config.counts
    out_dir = Path(config.out_dir) if config.out_dir is not None else None
    check_eval_outputs(Path(scene_dir), config.checkpoint, config.json_path, out_dir, config.overwrite)
    cache, claim = points_cache(config.points_cache, Path(scene_dir), out_dir, OWNER)
    if out_dir is not None:
        lock_output(out_dir, OWNER)  # one writer per folder (lock.py)
    scene = load_scene(Path(scene_dir))
    if (warning := walk_warning(scene)) is not None:
        print(warning, file=sys.stderr, flush=True)
    scene, _ = normalize_scene(scene)
    # --max-views scores fewer views of the same protocol: the unscored held-out views stay out of the references
    # and the triangulation, so each score equals that view's score in the full run.
    held = held_out_views(scene)
    scored = evenly_spread(held, config.max_views)
    size = scene.size_for(config.resolution)
    if min(size) < SSIM_WINDOW:
        raise UserError(f"--resolution gives {size[1]}x{size[0]} images, smaller than SSIM's {SSIM_WINDOW}-px window")
    weights = checkpoint_path(config.checkpoint)
    model = load_model(weights, config.device)  # a bad checkpoint fails before the triangulation's half minute
    prepare_side_by_sides(out_dir, scored, counts)  # an earlier eval's outputs go first; its SfM points stay
    if config.sfm_depth:  # from the references alone: a held-out photo lends nothing to its own render
        scene = with_points(scene, [i for i in range(len(scene)) if i not in held], cache, claim)
    spec = RendererSpec(weights, scene, size, max(counts), config.device, config.chunk, config.exact,
                        config.sfm_depth, config.options)
    renderer = spec.build(model)
    work = HeldOutView(tuple(held), tuple(counts), out_dir)
    workers = worker_count(config.workers, len(scored), config.device)
    by_view: dict[int, tuple[ViewScore, ...]] = {}
    bar = tqdm(total=len(scored), unit="view", desc="evaluating", file=sys.stderr, dynamic_ncols=True)
    if workers > 1:
        bar.set_postfix_str(f"{workers} processes", refresh=False)
    with bar:
        for index, view_scores, _ in run_side_by_side(renderer, spec, work, list(scored), workers):
            by_view[index] = view_scores
            bar.update(1)
    scores = {n: [by_view[index][counts.index(n)] for index in scored] for n in counts}
    reports = tuple(EvalReport(Path(scene_dir), size[0], size[1], float(np.mean([s.psnr for s in scores[n]])),
                               float(np.mean([s.ssim for s in scores[n]])), tuple(scores[n]), n) for n in counts)
    run = EvalRun(config, weights, reports, time.perf_counter() - started)
    if out_dir is not None:
        write_bytes(out_dir / REPORT_HTML, eval_page(run).encode("utf-8"))
    if config.json_path is not None:
        write_json(config.json_path, run.to_json())
    return run


@dataclass(frozen=True)
class HeldOutView:
    """Scoring one held-out view at every count (work for processes.run_side_by_side): the view rendered from its
    ``counts`` nearest references outside ``held`` at the renderer's size, scored against its photo, and with an
    ``out_dir`` its side-by-sides written there."""

    held: tuple[int, ...]
    counts: tuple[int, ...]
    out_dir: Path | None

    def run(self, renderer: ViewRenderer, index: int) -> tuple[ViewScore, ...]:
        """The ViewScore of view ``index`` at each count, in the order of ``counts``."""
        scene, held, size = renderer.scene, list(self.held), renderer.size
        camera = scene.cameras.subset([index]).rescale(*size)
        truth = scene.load_image(index, *size).astype(np.float64)
        scores: dict[int, ViewScore] = {}
        # Most references first: the smaller counts' nearest views are among them, already encoded.
        for n in reversed(self.counts):
            start = time.perf_counter()
            out, refs = renderer.render(camera, float(scene.near[index]), float(scene.far[index]), held, n)
            if set(refs) & set(held):  # nearest_views honours exclude; this guards the metric's meaning
                raise RuntimeError(f"held-out views {sorted(set(refs) & set(held))} were chosen as references")
            render = out.rgb.double().cpu().numpy()
            scores[n] = ViewScore(index, scene.names[index], psnr(render, truth), ssim(render, truth), tuple(refs),
                                  time.perf_counter() - start)
            if self.out_dir is not None:
                write_png(self.out_dir / side_by_side_name(index, n, len(self.counts) > 1),
                          side_by_side(render, truth))
        return tuple(scores[n] for n in self.counts)
