"""What `insertnerf eval` writes: the JSON report, and in --out the side-by-sides (render | truth | error) and
report.html, each recorded in --out's .insertnerf-outputs.json before it is made (outdir.py)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from insertnerf_cli.errors import UserError
from insertnerf_cli.exporters.outputs import FRAME_GLOB, POINTS_DIR, frame_name, to_uint8
from insertnerf_cli.files.outdir import OutputRecord, check_output, holds_files

OWNER = "eval"
REPORT_HTML = "report.html"
# Side-by-sides that eval versions without an output record wrote (what --overwrite removes from such a folder).
_EVAL_LEGACY_OUTPUTS = (FRAME_GLOB,)
# Absolute colour error that maps to the top of the colour map in eval's side-by-sides: errors past a quarter of
# the range are already glaring, and a fixed scale keeps images of different views comparable.
ERROR_VIS_MAX = 0.25


def check_eval_outputs(scene_dir: Path, checkpoint: Path | None, json_path: Path | None, out_dir: Path | None,
                       overwrite: bool) -> None:
    """Refuse, before any work, eval outputs inside the inputs or not writable, and replacing an existing report
    or side-by-sides without overwrite."""
    inputs = [scene_dir, checkpoint]
    if json_path is not None:
        check_output(Path(json_path), inputs, is_dir=False, what="--json", kind="input scene or checkpoint")
    if out_dir is not None:
        check_output(Path(out_dir), inputs, kind="input scene or checkpoint")
    if overwrite:
        return
    if json_path is not None and Path(json_path).exists():
        raise UserError(f"{json_path} exists; pass --overwrite to replace it or choose another --json")
    if out_dir is not None and holds_files(Path(out_dir)):
        raise UserError(f"{out_dir} is not empty; pass --overwrite to replace the images insertnerf wrote "
                        "there (other files are kept) or choose another --out")


def side_by_side_name(index: int, views: int, several: bool) -> str:
    """Where the side-by-side of held-out view ``index`` rendered from ``views`` references goes in --out: flat
    (00006.png) for one count, one folder per count (views_10/00006.png) for a list of counts."""
    return f"views_{views}/{frame_name(index)}" if several else frame_name(index)


def prepare_side_by_sides(out_dir: Path | None, held: Sequence[int], counts: Sequence[int]) -> None:
    """Remove the outputs of an earlier eval (only ours) and record the ones this run writes."""
    if out_dir is None:
        return
    record = OutputRecord(out_dir, OWNER)
    record.remove(legacy=_EVAL_LEGACY_OUTPUTS, keep=(POINTS_DIR,))  # the SfM points stay: keyed by the scene
    several = len(counts) > 1
    folders = [f"views_{n}" for n in counts] if several else []
    record.claim(*folders, *(side_by_side_name(i, n, several) for n in counts for i in held), REPORT_HTML)


def side_by_side(render: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """[H, 3W, 3] uint8: render | truth | per-pixel mean absolute error (turbo, 0 to ERROR_VIS_MAX)."""
    import cv2

    error = np.abs(render.astype(np.float64) - truth).mean(-1) / ERROR_VIS_MAX
    error_rgb = cv2.applyColorMap(to_uint8(np.clip(error, 0, 1)[..., None])[..., 0], cv2.COLORMAP_TURBO)[..., ::-1]
    return np.concatenate([to_uint8(render), to_uint8(truth), error_rgb], axis=1)
