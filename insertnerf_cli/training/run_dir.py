"""The files of a training run:

    RUN_DIR/metrics.jsonl           one JSON object per line (training averages and validations)
    RUN_DIR/splits.json             which scenes trained and which were held out
    RUN_DIR/checkpoints/last.pt     the latest checkpoint (weights, model config, optimizer, step, RNG)
    RUN_DIR/checkpoints/best.pt     the checkpoint with the best validation PSNR so far
    RUN_DIR/checkpoints/config.json the model and training configs, for people and scripts to read

Each is recorded in RUN_DIR/.insertnerf-outputs.json before it is written (outdir.py), and --overwrite removes
only those: a user's own file in RUN_DIR or RUN_DIR/checkpoints stays.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from insertnerf_cli.config import config_to_json
from insertnerf_cli.errors import UserError
from insertnerf_cli.files.atomic import atomic_path, write_error, write_json
from insertnerf_cli.files.outdir import OutputRecord, check_not_inside_inputs, check_output
from insertnerf_cli.training.config import TrainConfig

OWNER = "train"  # the name of its list in an output record (outdir.py)


@dataclass(frozen=True)
class RunFiles:
    root: Path

    @property
    def metrics(self) -> Path:
        return self.root / "metrics.jsonl"

    @property
    def splits(self) -> Path:
        return self.root / "splits.json"

    @property
    def checkpoints(self) -> Path:
        return self.root / "checkpoints"

    @property
    def last(self) -> Path:
        return self.checkpoints / "last.pt"

    @property
    def best(self) -> Path:
        return self.checkpoints / "best.pt"

    @property
    def config(self) -> Path:
        return self.checkpoints / "config.json"

    def owned(self) -> list[Path]:
        """Everything a run writes (what --overwrite deletes; other files in RUN_DIR are left alone)."""
        return [self.metrics, self.splits, self.checkpoints, self.last, self.best, self.config]

    def has_checkpoint(self) -> bool:
        return self.last.is_file() or self.best.is_file()

    def has_run(self) -> bool:
        """Whether a run wrote anything here (a record, or files of versions before records)."""
        return OutputRecord(self.root, OWNER).exists or any(p.exists() for p in self.owned())


def check_run_dir(files: RunFiles, dataset_dir: Path, resume: bool, overwrite: bool,
                  init: str | None = None) -> None:
    """Refuse to mix runs: a RUN_DIR with a checkpoint needs --resume or --overwrite, and --resume needs one.

    A run folder killed before its first checkpoint holds nothing to resume: a plain run starts it afresh.
    The folder must not hold or lie inside the dataset or the --init checkpoint, and must be writable.
    """
    if resume and overwrite:
        raise UserError("--resume and --overwrite contradict each other: pick one.")
    if init is not None and not resume:
        check_not_inside_inputs(files.root, [Path(init)], kind="--init checkpoint")
    check_output(files.root, [dataset_dir], kind="input dataset")
    if resume:
        if not files.last.is_file():
            raise UserError(f"nothing to resume: {files.last} does not exist; start a new run without --resume "
                            "(the same command without it).")
        return
    if files.has_checkpoint() and not overwrite:
        raise UserError(f"{files.root} already holds a training run; continue it with --resume, replace it with "
                        "--overwrite, or pass another --out.")


def clear_run(files: RunFiles) -> None:
    """Delete the files of a previous run in RUN_DIR (only those insertnerf wrote), for --overwrite."""
    OutputRecord(files.root, OWNER).remove(legacy=_LEGACY_OUTPUTS)


def claim_run(files: RunFiles) -> None:
    """Record every file of the run before writing any."""
    OutputRecord(files.root, OWNER).claim(*(p.relative_to(files.root).as_posix() for p in files.owned()))


# What runs of versions without an output record wrote (the only names --overwrite removes there).
_LEGACY_OUTPUTS = ("metrics.jsonl", "splits.json", "checkpoints/last.pt", "checkpoints/best.pt",
                   "checkpoints/config.json", "checkpoints/")


def write_run_config(files: RunFiles, config: TrainConfig, dataset_dir: Path) -> None:
    write_json(files.config, {"dataset": str(dataset_dir), "model": config_to_json(config.model),
                              "train": config_to_json(config)})


def append_metrics(files: RunFiles, record: dict[str, Any]) -> None:
    """Append one JSON line and flush, so a crash loses at most the line being written."""
    try:
        with open(files.metrics, "a", encoding="utf-8") as handle:
            handle.write(json.dumps(record) + "\n")
    except OSError as err:
        raise write_error(files.metrics, err) from None


def truncate_metrics(files: RunFiles, step: int) -> None:
    """Drop metric lines after ``step`` (written after the checkpoint a resumed run restarts from)."""
    if not files.metrics.is_file():
        return
    lines = files.metrics.read_text(encoding="utf-8").splitlines()
    kept = [line for line in lines if _step_of(line) <= step]
    if len(kept) != len(lines):
        with atomic_path(files.metrics) as tmp:
            tmp.write_text("".join(line + "\n" for line in kept), encoding="utf-8")


def _step_of(line: str) -> float:
    try:
        return float(json.loads(line).get("step", 0))
    except (ValueError, AttributeError):
        return float("inf")  # an unreadable (half-written) line goes


def write_splits(files: RunFiles, train: list[str], val: list[str]) -> None:
    write_json(files.splits, {"train": train, "val": val})


def read_splits(files: RunFiles) -> tuple[list[str], list[str]]:
    try:
        data = json.loads(files.splits.read_text(encoding="utf-8"))
        return [str(n) for n in data["train"]], [str(n) for n in data["val"]]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise UserError(f"{files.splits} cannot be read ({err}); the run folder is damaged: start a new run.") from None
