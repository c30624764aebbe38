"""Cases of bench/hostile.py for two writers of one output at once (issue 29).

The first writer runs alongside the step and is frozen once it holds its output's lock, so the second always
meets it: the second must be refused in one line naming the first's pid, the first must finish (exit 0), and the
output must be whole and self-consistent (`consistent`: else the case counts as corrupt). A writer killed with
kill -9 leaves a lock file that is no lock: the next run must take it.
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import torch
from hostile_finetune import finetune_args
from hostile_kit import (KILL, Plan, Step, Workspace, case, eval_args, frames_decodable, poses_args, render_args,
                         synth_args, train_args)

from insertnerf_cli.files.lock import lock_file

LOCK = ".insertnerf-lock"


def _no_lock_left(*paths: Path) -> str | None:
    left = [str(p) for p in paths if p.exists()]
    return f"lock file left after the writers finished: {left}" if left else None


def render_consistent(out: Path) -> str | None:
    """cameras.json lists exactly the frames on disk, every frame decodes and all have one size."""
    try:
        listed = len(json.loads((out / "cameras.json").read_text())["frames"])
    except (OSError, ValueError, KeyError) as err:
        return f"cameras.json unreadable: {err}"
    problem = frames_decodable(out)
    if problem:
        return problem
    for kind in ("frames", "depth", "depth_vis"):
        files = sorted((out / kind).glob("*.png"))
        if len(files) != listed:
            return f"{kind}/ holds {len(files)} images, cameras.json lists {listed}"
        shapes = {cv2.imread(str(p), cv2.IMREAD_UNCHANGED).shape[:2] for p in files}
        if len(shapes) != 1:
            return f"{kind}/ holds images of {len(shapes)} sizes: {sorted(shapes)}"
    return _no_lock_left(out / LOCK)


def run_consistent(run: Path, steps: int) -> str | None:
    """metrics.jsonl counts each step once, in order, up to ``steps``; last.pt loads at that step."""
    records = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line.strip()]
    logged = [r["step"] for r in records if r.get("split") == "train"]
    if logged != sorted(set(logged)):
        return f"metrics.jsonl logs steps out of order or twice: {logged[:12]}"
    try:
        state = torch.load(run / "checkpoints" / "last.pt", map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any failure to load is the finding
        return f"last.pt does not load: {err}"
    step = state.get("train", {}).get("step")
    if step != steps:
        return f"last.pt is at step {step}, expected {steps}"
    return _no_lock_left(run / LOCK)


@case
def case_render_second_writer_overwrite_while_first_renders(w: Workspace) -> Plan:
    scene, out = w.scene(), w.dir / "out"
    first = render_args(w.fx, scene, out, "--frames", "3")
    second = render_args(w.fx, scene, out, "--frames", "2", "--resolution", "24", "--overwrite")
    return Plan([Step(second, alongside=first, holds=out / LOCK)], inputs=[scene],
                consistent=lambda: render_consistent(out))


@case
def case_render_kill_9_leaves_a_stale_lock_then_rerun(w: Workspace) -> Plan:
    scene, out = w.scene(), w.dir / "out"
    args = render_args(w.fx, scene, out, "--frames", "30")
    return Plan([Step(args, "any", signal=(KILL, "rendering", 0.2)), Step(args, "ok")], inputs=[scene],
                consistent=lambda: render_consistent(out))


@case
def case_train_two_resumes_of_one_run(w: Workspace) -> Plan:
    data, run = w.dataset(), w.dir / "run"
    resume = train_args(w.fx, data, run, "--resume", "--steps", "12")
    return Plan([Step(train_args(w.fx, data, run), "ok"), Step(resume, alongside=resume, holds=run / LOCK)],
                inputs=[data], consistent=lambda: run_consistent(run, 12))


@case
def case_train_second_writer_fresh_run_into_one_folder(w: Workspace) -> Plan:
    data, run = w.dataset(), w.dir / "run"
    args = train_args(w.fx, data, run)
    return Plan([Step(args, alongside=args, holds=run / LOCK)], inputs=[data], consistent=lambda: run_consistent(run, 2))


@case
def case_eval_two_writers_of_one_out(w: Workspace) -> Plan:
    scene, out = w.scene(), w.dir / "side"
    args = eval_args(w.fx, scene, "--out", str(out), "--overwrite")

    def consistent() -> str | None:
        images = sorted(out.glob("*.png"))
        bad = [p.name for p in images if cv2.imread(str(p)) is None]
        return (f"side-by-sides: {len(images)} images, undecodable {bad}" if len(images) != 1 or bad
                else _no_lock_left(out / LOCK))

    return Plan([Step(args, alongside=args, holds=out / LOCK)], inputs=[scene], consistent=consistent)


@case
def case_finetune_two_writers_of_one_out(w: Workspace) -> Plan:
    scene, out = w.scene(), w.dir / "ft.pt"
    first = finetune_args(w.fx, scene, out)
    second = finetune_args(w.fx, scene, out, "--overwrite")

    def consistent() -> str | None:
        try:
            torch.load(out, map_location="cpu", weights_only=True)
        except Exception as err:  # noqa: BLE001
            return f"ft.pt does not load: {err}"
        return _no_lock_left(lock)

    lock = lock_file(out, is_dir=False)  # beside the checkpoint
    return Plan([Step(second, alongside=first, holds=lock)], inputs=[scene], consistent=consistent)


@case
def case_synth_two_writers_of_one_folder(w: Workspace) -> Plan:
    out = w.dir / "synth"
    args = synth_args(out, "--scenes", "2")

    def consistent() -> str | None:
        scenes = sorted(p for p in out.iterdir() if p.is_dir() and p.name.startswith("scene_"))
        unfinished = [p.name for p in scenes if not (p / "scene.json").is_file()]
        if len(scenes) != 2 or unfinished or not (out / "manifest.json").is_file():
            return f"{len(scenes)} scene folders (2 expected), unfinished {unfinished}"
        return _no_lock_left(out / LOCK)

    return Plan([Step(args, alongside=args, holds=out / LOCK)], consistent=consistent)


@case
def case_poses_two_writers_of_one_out(w: Workspace) -> Plan:
    photos, out = w.photos(), w.dir / "scene"
    first = poses_args(photos, out)
    second = poses_args(photos, out, "--overwrite")

    def consistent() -> str | None:
        from insertnerf_cli.scenes import SceneError, load_scene

        try:
            views = len(load_scene(out))
        except SceneError as err:
            return f"the posed scene does not load: {err}"
        return f"{views} views, expected 16" if views != 16 else _no_lock_left(lock)

    lock = lock_file(out, is_dir=False)  # beside the folder: a killed run leaves no folder that is not a scene
    return Plan([Step(second, alongside=first, holds=lock)], inputs=[photos], consistent=consistent)
