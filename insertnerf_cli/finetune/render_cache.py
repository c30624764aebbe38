"""`render --finetune M`: fine-tune for M minutes once, keep the result in the output folder, reuse it after.

OUT/finetune.pt holds the weights; OUT/finetune.json the settings they were made with and the file's SHA-256.
A re-run with the same scene, base weights and settings reuses them; anything else fine-tunes again. The
record is written only after a completed run, so an interrupted fine-tune is never taken for a finished one.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import torch

from insertnerf_cli.config import config_to_json
from insertnerf_cli.files.atomic import write_json
from insertnerf_cli.finetune.loop import FinetuneConfig, finetune
from insertnerf_cli.model.checkpoint import checkpoint_sha256
from insertnerf_cli.scenes.points import ScenePoints

WEIGHTS = "finetune.pt"
RECORD = "finetune.json"


def cached_finetune(scene_dir: Path, out_dir: Path, base: Path, config: FinetuneConfig,
                    device: torch.device, points: ScenePoints | None = None) -> Path:
    """OUT/finetune.pt fine-tuned from ``base`` on ``scene_dir`` with ``config``, made now unless a completed
    earlier run with the same inputs left it there (``points``: as finetune's).

    Raises:
        KeyboardInterrupt: Ctrl-C stopped the fine-tune (the partial weights are not recorded as finished).
    """
    weights, record = out_dir / WEIGHTS, out_dir / RECORD
    key = {"scene": str(Path(scene_dir).resolve()), "base_sha256": checkpoint_sha256(base),
           "config": config_to_json(config)}
    done = _read(record)
    if done.get("key") == key and weights.is_file() and done.get("sha256") == checkpoint_sha256(weights):
        print(f"reusing the fine-tuned weights in {weights} (same scene, base and settings)", file=sys.stderr)
        return weights
    record.unlink(missing_ok=True)
    result = finetune(scene_dir, weights, config, device, base=base, overwrite=True, points=points)
    if result.stopped == "interrupted" or result.checkpoint is None:
        raise KeyboardInterrupt
    write_json(record, {"key": key, "sha256": checkpoint_sha256(weights), "steps": result.steps,
                        "minutes": result.elapsed_s / 60.0, "train_psnr": result.train_psnr})
    return weights


def _read(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}
