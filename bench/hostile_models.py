"""Cases of bench/hostile.py for choosing weights: `render/eval --model` beside --checkpoint, and `train --init`
(a corrupt or foreign checkpoint, one inside the run folder that --overwrite clears). Expectations as in
hostile_cases.py."""
from __future__ import annotations

import shutil
from pathlib import Path

import torch
from hostile_kit import Plan, Step, Workspace, case, eval_args, render_args, train_args

BUNDLED = Path(__file__).resolve().parents[1] / "insertnerf_cli" / "weights" / "insertnerf.pt"


@case
def case_render_model_full_and_checkpoint(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(render_args(w.fx, scene, w.dir / "out", "--model", "full"))], inputs=[scene])


@case
def case_render_default_model_named_and_checkpoint(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(render_args(w.fx, scene, w.dir / "out", "--model", "fast"))], inputs=[scene])


@case
def case_eval_model_fast_and_checkpoint(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(eval_args(w.fx, scene, "--model", "fast"))], inputs=[scene])


@case
def case_train_init_valid(w: Workspace) -> Plan:
    data, init = w.dataset(), Path(shutil.copy(w.fx.ckpt, w.dir / "init.pt"))
    return Plan([Step(train_args(w.fx, data, w.dir / "run", "--init", str(init)), "ok")], inputs=[data, init])


@case
def case_train_init_not_a_checkpoint(w: Workspace) -> Plan:
    data, bad = w.dataset(), w.file("weights.pt", "not a checkpoint\n")
    return Plan([Step(train_args(w.fx, data, w.dir / "run", "--init", str(bad)))], inputs=[data], foreign=[bad])


@case
def case_train_init_other_architecture(w: Workspace) -> Plan:
    data = w.dataset()  # the tiny config of the fixtures against the bundled generator's widths
    return Plan([Step(train_args(w.fx, data, w.dir / "run", "--init", str(BUNDLED)))], inputs=[data])


@case
def case_train_init_inside_run_overwrite(w: Workspace) -> Plan:
    data, run = w.dataset(), w.dir / "run"
    last = run / "checkpoints" / "last.pt"

    def last_survives() -> str | None:
        try:
            torch.load(last, map_location="cpu", weights_only=True)
        except Exception as err:  # noqa: BLE001 - any failure to load is the finding
            return f"the --init checkpoint inside the run folder was lost: {err}"
        return None

    return Plan([Step(train_args(w.fx, data, run), "ok"),
                 Step(train_args(w.fx, data, run, "--overwrite", "--init", str(last)))],
                inputs=[data], check=last_survives)
