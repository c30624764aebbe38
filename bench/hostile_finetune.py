"""Cases of bench/hostile.py for `insertnerf finetune` and `render --finetune`: its --out beside or inside its
inputs (the scene and the checkpoint it starts from), bad checkpoints and options, permissions, disk full, Ctrl-C,
and --overwrite keeping the user's files. Expectations as in hostile_cases.py."""
from __future__ import annotations

import shutil
from pathlib import Path

import torch
from hostile_kit import INT, Fixtures, Plan, Step, Workspace, case, fill_disk, render_args


def finetune_args(fx: Fixtures, scene: Path, out: Path, *extra: str, base: Path | None = None,
                  budget: tuple[str, ...] = ("--steps", "2")) -> list[str]:
    return ["finetune", str(scene), "--out", str(out), "--checkpoint", str(base or fx.ckpt), *budget,
            "--rays", "16", "--views", "2", "--resolution", "32", "--device", "cpu", *extra]


def _loads(path: Path) -> str | None:
    try:
        torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any failure to load is the finding
        return f"{path.name} does not load with weights_only=True: {err}"
    return None


@case
def case_finetune_valid(w: Workspace) -> Plan:
    scene, out = w.scene(), w.dir / "ft.pt"
    return Plan([Step(finetune_args(w.fx, scene, out), "ok")], inputs=[scene], check=lambda: _loads(out))


@case
def case_finetune_out_is_its_base_checkpoint_overwrite(w: Workspace) -> Plan:
    scene, base = w.scene(), Path(shutil.copy(w.fx.ckpt, w.dir / "base.pt"))
    return Plan([Step(finetune_args(w.fx, scene, base, "--overwrite", base=base))], inputs=[scene, base])


@case
def case_finetune_out_inside_scene_overwrite(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(finetune_args(w.fx, scene, scene / "ft.pt", "--overwrite"))], inputs=[scene])


@case
def case_finetune_out_parent_is_file(w: Workspace) -> Plan:
    scene, blocker = w.scene(), w.file("notes.txt")
    return Plan([Step(finetune_args(w.fx, scene, blocker / "ft.pt"))], inputs=[scene], foreign=[blocker])


@case
def case_finetune_out_is_a_folder(w: Workspace) -> Plan:
    scene, mine = w.scene(), w.file("results/mine.txt")
    return Plan([Step(finetune_args(w.fx, scene, mine.parent, "--overwrite"))], inputs=[scene], foreign=[mine])


@case
def case_finetune_out_exists_without_overwrite(w: Workspace) -> Plan:
    scene, mine = w.scene(), w.file("ft.pt", "the user's own weights\n")
    return Plan([Step(finetune_args(w.fx, scene, mine))], inputs=[scene], foreign=[mine])


@case
def case_finetune_checkpoint_is_not_a_checkpoint(w: Workspace) -> Plan:
    scene, junk = w.scene(), w.file("junk.pt", "not a checkpoint\n")
    return Plan([Step(finetune_args(w.fx, scene, w.dir / "ft.pt", base=junk))], inputs=[scene, junk])


@case
def case_finetune_unposed_photos(w: Workspace) -> Plan:
    photos = w.photos(count=6)
    return Plan([Step(finetune_args(w.fx, photos, w.dir / "ft.pt"))], inputs=[photos])


@case
def case_finetune_minutes_nan(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(finetune_args(w.fx, scene, w.dir / "ft.pt", budget=("--minutes", "nan")))], inputs=[scene])


@case
def case_finetune_read_only_out_folder(w: Workspace) -> Plan:
    scene, folder = w.scene(), w.dir / "ro"
    folder.mkdir()
    return Plan([Step(finetune_args(w.fx, scene, folder / "ft.pt"), nobody=True)], inputs=[scene],
                locks=[(folder, 0o555)])


@case
def case_finetune_disk_full(w: Workspace) -> Plan | str:
    scene, disk = w.scene(), w.tmpfs("disk", 512)
    if disk is None:
        return "cannot mount a tmpfs here (needs root)"
    return Plan([Step(finetune_args(w.fx, scene, disk / "ft.pt"), before=fill_disk(disk, 8))], inputs=[scene])


@case
def case_finetune_ctrl_c_during_work_saves(w: Workspace) -> Plan:
    scene, out = w.scene(), w.dir / "ft.pt"
    args = finetune_args(w.fx, scene, out, budget=("--steps", "1000000"))
    return Plan([Step(args, "interrupt", signal=(INT, "fine-tuning", 2.0))],
                inputs=[scene], check=lambda: _loads(out) if out.exists() else "Ctrl-C saved no weights")


@case
def case_render_finetune_overwrite_keeps_foreign_files(w: Workspace) -> Plan:
    scene, out = w.scene(), w.dir / "out"
    args = render_args(w.fx, scene, out, "--views", "2", "--finetune", "0.01")
    mine = out / "notes.txt"
    return Plan([Step(args, "ok"), Step(args + ["--overwrite"], "ok", before=lambda: w.file("out/notes.txt"))],
                inputs=[scene], check=lambda: None if mine.is_file() else "render --overwrite removed notes.txt")
