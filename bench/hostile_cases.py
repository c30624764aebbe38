"""Cases of bench/hostile.py about OUTPUTS and FAULTS: valid runs, output paths (a file as parent, the input
itself), the user's files under --overwrite, permissions, disk full, power loss, Ctrl-C and kill -9.

Expectations follow the developer brief and issue 12: bad input -> a short error and exit 1-125; valid input ->
exit 0; inputs and the user's files survive unchanged; nothing is written inside an input.
"""
from __future__ import annotations

import shutil
from pathlib import Path
from typing import Callable

from hostile_kit import (INT, KILL, Plan, Step, Workspace, case, eval_args, fill_disk, frames_decodable, poses_args,
                         render_args, synth_args, train_args)


# ---------------------------------------------------------------- valid runs: the harness itself can pass
@case
def case_synth_valid(w: Workspace) -> Plan:
    return Plan([Step(synth_args(w.dir / "out"), "ok")])


@case
def case_train_valid(w: Workspace) -> Plan:
    data = w.dataset()
    return Plan([Step(train_args(w.fx, data, w.dir / "run"), "ok")], inputs=[data])


@case
def case_render_valid_then_rerun_resumes(w: Workspace) -> Plan:
    scene = w.scene()
    args = render_args(w.fx, scene, w.dir / "out")
    return Plan([Step(args, "ok"), Step(args, "ok")], inputs=[scene])


@case
def case_eval_valid(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(eval_args(w.fx, scene, "--json", str(w.dir / "s.json"), "--out", str(w.dir / "sbs")), "ok")],
                inputs=[scene])


@case
def case_poses_valid(w: Workspace) -> Plan:
    photos = w.photos()
    return Plan([Step(poses_args(photos, w.dir / "scene"), "ok")], inputs=[photos])


# ---------------------------------------------------------------- an output path whose parent is a file
def _parent_is_file(w: Workspace, make_args: Callable[[Path], list[str]], inputs: list[Path]) -> Plan:
    blocker = w.file("notes.txt")
    return Plan([Step(make_args(blocker / "out"))], inputs=inputs, foreign=[blocker])


@case
def case_poses_out_parent_is_file(w: Workspace) -> Plan:
    photos = w.photos(count=4)
    return _parent_is_file(w, lambda out: poses_args(photos, out), [photos])


@case
def case_synth_out_parent_is_file(w: Workspace) -> Plan:
    return _parent_is_file(w, synth_args, [])


@case
def case_train_out_parent_is_file(w: Workspace) -> Plan:
    data = w.dataset()
    return _parent_is_file(w, lambda out: train_args(w.fx, data, out), [data])


@case
def case_render_out_parent_is_file(w: Workspace) -> Plan:
    scene = w.scene()
    return _parent_is_file(w, lambda out: render_args(w.fx, scene, out), [scene])


@case
def case_eval_json_parent_is_file(w: Workspace) -> Plan:
    scene = w.scene()
    return _parent_is_file(w, lambda out: eval_args(w.fx, scene, "--json", str(out / "s.json")), [scene])


@case
def case_eval_out_parent_is_file(w: Workspace) -> Plan:
    scene = w.scene()
    return _parent_is_file(w, lambda out: eval_args(w.fx, scene, "--out", str(out)), [scene])


@case
def case_render_out_is_a_file(w: Workspace) -> Plan:
    scene, blocker = w.scene(), w.file("notes.txt")
    return Plan([Step(render_args(w.fx, scene, blocker, "--overwrite"))], inputs=[scene], foreign=[blocker])


@case
def case_train_out_is_a_file(w: Workspace) -> Plan:
    data, blocker = w.dataset(), w.file("notes.txt")
    return Plan([Step(train_args(w.fx, data, blocker, "--overwrite"))], inputs=[data], foreign=[blocker])


# ---------------------------------------------------------------- output is, contains or lies in the input
@case
def case_render_out_is_input_overwrite(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(render_args(w.fx, scene, scene, "--overwrite"))], inputs=[scene])


@case
def case_render_out_inside_input_overwrite(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(render_args(w.fx, scene, scene / "views", "--overwrite"))], inputs=[scene])


@case
def case_render_out_contains_photo_input_overwrite(w: Workspace) -> Plan:
    """Issue 12 allows refusing or rendering beside the photos; the photos must survive either way."""
    photos = w.photos("shoot/frames")
    return Plan([Step(render_args(w.fx, photos, w.dir / "shoot", "--overwrite"), "any")], inputs=[photos])


@case
def case_eval_out_is_input_overwrite(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(eval_args(w.fx, scene, "--out", str(scene), "--overwrite"))], inputs=[scene])


@case
def case_eval_json_is_an_input_file_overwrite(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(eval_args(w.fx, scene, "--json", str(scene / "transforms_test.json"), "--overwrite"))],
                inputs=[scene])


@case
def case_poses_out_is_input_overwrite(w: Workspace) -> Plan:
    photos = w.photos(count=4)
    return Plan([Step(poses_args(photos, photos, "--overwrite"))], inputs=[photos])


@case
def case_poses_out_inside_input_overwrite(w: Workspace) -> Plan:
    photos = w.photos(count=4)
    return Plan([Step(poses_args(photos, photos / "scene", "--overwrite"))], inputs=[photos])


@case
def case_train_out_is_input_overwrite(w: Workspace) -> Plan:
    data = w.dataset()
    return Plan([Step(train_args(w.fx, data, data, "--overwrite"))], inputs=[data])


@case
def case_train_out_inside_input_overwrite(w: Workspace) -> Plan:
    data = w.dataset()
    return Plan([Step(train_args(w.fx, data, data / "run", "--overwrite"))], inputs=[data])


@case
def case_train_out_contains_input_overwrite(w: Workspace) -> Plan:
    """Refusing or training beside the dataset are both fine; the dataset must survive either way."""
    data = Path(shutil.copytree(w.fx.data, w.dir / "project" / "data"))
    return Plan([Step(train_args(w.fx, data, w.dir / "project", "--overwrite"), "any")], inputs=[data])


@case
def case_synth_out_is_a_training_dataset_overwrite(w: Workspace) -> Plan:
    """Regenerating with other options over a dataset holding a user's own scene and notes keeps them."""
    data = w.dataset()
    mine = [w.file("data/scene_00000/notes.txt"), w.file("data/scene_mine/notes.txt"), w.file("data/README.txt")]
    return Plan([Step(synth_args(data, "--overwrite"), "ok")], foreign=mine)


# ---------------------------------------------------------------- the user's files in an output folder, --overwrite
@case
def case_render_overwrite_keeps_foreign_files(w: Workspace) -> Plan:
    scene, out = w.scene(), Path(shutil.copytree(w.fx.render_out, w.dir / "out"))
    mine = [w.file("out/notes.txt"), w.file("out/frames/mine.txt"), w.file("out/depth/keep/a.txt")]
    return Plan([Step(render_args(w.fx, scene, out, "--frames", "3", "--overwrite"), "ok")],
                inputs=[scene], foreign=mine)


@case
def case_eval_overwrite_keeps_foreign_files(w: Workspace) -> Plan:
    scene = w.scene()
    mine = [w.file("sbs/notes.txt"), w.file("sbs/00000_mine.png", "not an image\n")]
    report = w.file("s.json", "{}\n")
    return Plan([Step(eval_args(w.fx, scene, "--json", str(report), "--out", str(w.dir / "sbs"), "--overwrite"),
                      "ok")], inputs=[scene], foreign=mine)


@case
def case_train_overwrite_keeps_foreign_files(w: Workspace) -> Plan:
    data, run = w.dataset(), Path(shutil.copytree(w.fx.run, w.dir / "run"))
    mine = [Path(shutil.copy(run / "checkpoints" / "last.pt", run / "checkpoints" / "keep_step2.pt")),
            w.file("run/notes.txt")]
    return Plan([Step(train_args(w.fx, data, run, "--overwrite"), "ok")], inputs=[data], foreign=mine)


@case
def case_poses_overwrite_keeps_foreign_files(w: Workspace) -> Plan:
    photos, scene = w.photos(), Path(shutil.copytree(w.fx.room_scene, w.dir / "scene"))
    mine = [w.file("scene/notes.txt"), w.file("scene/images/mine.txt")]
    return Plan([Step(poses_args(photos, scene, "--overwrite"), "ok")], inputs=[photos], foreign=mine)


@case
def case_render_refuses_foreign_folder_without_overwrite(w: Workspace) -> Plan:
    scene, mine = w.scene(), w.file("out/notes.txt")
    return Plan([Step(render_args(w.fx, scene, mine.parent))], inputs=[scene], foreign=[mine])


@case
def case_synth_refuses_foreign_folder_without_overwrite(w: Workspace) -> Plan:
    mine = w.file("out/notes.txt")
    return Plan([Step(synth_args(mine.parent))], foreign=[mine])


@case
def case_eval_refuses_existing_json_without_overwrite(w: Workspace) -> Plan:
    scene, mine = w.scene(), w.file("scores.json", '{"mine": 1}\n')
    return Plan([Step(eval_args(w.fx, scene, "--json", str(mine)))], inputs=[scene], foreign=[mine])


# ---------------------------------------------------------------- permissions (run as user 65534)
@case
def case_render_read_only_out(w: Workspace) -> Plan:
    scene, out = w.scene(), w.dir / "out"
    out.mkdir()
    return Plan([Step(render_args(w.fx, scene, out), nobody=True)], inputs=[scene], locks=[(out, 0o555)])


@case
def case_eval_json_in_read_only_folder(w: Workspace) -> Plan:
    scene, folder = w.scene(), w.dir / "ro"
    folder.mkdir()
    return Plan([Step(eval_args(w.fx, scene, "--json", str(folder / "s.json")), nobody=True)], inputs=[scene],
                locks=[(folder, 0o555)])


@case
def case_synth_read_only_out(w: Workspace) -> Plan:
    out = w.dir / "out"
    out.mkdir()
    return Plan([Step(synth_args(out), nobody=True)], locks=[(out, 0o555)])


@case
def case_poses_read_only_parent(w: Workspace) -> Plan:
    photos, parent = w.photos(count=4), w.dir / "ro"
    parent.mkdir()
    return Plan([Step(poses_args(photos, parent / "scene"), nobody=True)], inputs=[photos], locks=[(parent, 0o555)])


@case
def case_render_unreadable_train_folder(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(render_args(w.fx, scene, w.dir / "out"), nobody=True)], inputs=[scene],
                locks=[(scene / "train", 0o000)])


@case
def case_eval_unreadable_image(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(eval_args(w.fx, scene), nobody=True)], inputs=[scene], locks=[(scene / "test" / "r_000.png", 0)])


@case
def case_poses_unreadable_photo(w: Workspace) -> Plan:
    photos = w.photos(count=4)
    return Plan([Step(poses_args(photos, w.dir / "scene"), nobody=True)], inputs=[photos],
                locks=[(sorted(photos.iterdir())[0], 0o000)])


@case
def case_train_skips_one_unreadable_scene(w: Workspace) -> Plan:
    data = w.dataset()
    return Plan([Step(train_args(w.fx, data, w.dir / "run"), "ok", nobody=True)], inputs=[data],
                locks=[(data / "scene_00001", 0o000)])


@case
def case_train_unreadable_dataset(w: Workspace) -> Plan:
    data = w.dataset()
    return Plan([Step(train_args(w.fx, data, w.dir / "run"), nobody=True)], inputs=[data], locks=[(data, 0o000)])


# ---------------------------------------------------------------- faults: disk full, power loss, Ctrl-C, kill -9
@case
def case_render_disk_full(w: Workspace) -> Plan | str:
    scene, disk = w.scene(), w.tmpfs("disk", 512)
    if disk is None:
        return "cannot mount a tmpfs here (needs root)"
    out = disk / "out"
    return Plan([Step(render_args(w.fx, scene, out, "--frames", "12", "--resolution", "48"),
                      before=fill_disk(disk, 24))], inputs=[scene], check=lambda: frames_decodable(out))


@case
def case_train_disk_full_keeps_last_checkpoint(w: Workspace) -> Plan | str:
    data, disk = w.dataset(), w.tmpfs("disk", 2048)
    if disk is None:
        return "cannot mount a tmpfs here (needs root)"
    run = Path(shutil.copytree(w.fx.run, disk / "run"))
    return Plan([Step(train_args(w.fx, data, run, "--resume", "--steps", "6"), before=fill_disk(disk, 60))],
                inputs=[data], foreign=[run / "checkpoints" / "last.pt"])


@case
def case_render_zero_byte_frame_is_rerendered(w: Workspace) -> Plan:
    scene, out = w.scene(), w.dir / "out"
    args = render_args(w.fx, scene, out, "--frames", "3")

    def power_loss() -> None:
        (out / "frames" / "00001.png").write_bytes(b"")
        (out / "depth" / "00002.png").write_bytes(b"")

    return Plan([Step(args, "ok"), Step(args, "ok", before=power_loss)], inputs=[scene],
                check=lambda: frames_decodable(out))


@case
def case_render_ctrl_c_during_start_up(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(render_args(w.fx, scene, w.dir / "out"), "interrupt", signal=(INT, "", 0.4))], inputs=[scene])


@case
def case_train_ctrl_c_during_start_up(w: Workspace) -> Plan:
    data = w.dataset()
    return Plan([Step(train_args(w.fx, data, w.dir / "run"), "interrupt", signal=(INT, "", 0.4))], inputs=[data])


@case
def case_render_ctrl_c_during_work_then_resume(w: Workspace) -> Plan:
    scene, out = w.scene(), w.dir / "out"
    args = render_args(w.fx, scene, out, "--frames", "200", "--resolution", "64")
    return Plan([Step(args, "interrupt", signal=(INT, "rendering", 1.5)), Step(args, "ok")], inputs=[scene],
                check=lambda: frames_decodable(out))


@case
def case_train_ctrl_c_during_work_saves(w: Workspace) -> Plan:
    data, run = w.dataset(), w.dir / "run"
    args = train_args(w.fx, data, run, "--steps", "100000", "--ckpt-every", "100000")
    return Plan([Step(args, "interrupt", signal=(INT, "training", 1.5))], inputs=[data],
                check=lambda: None if (run / "checkpoints" / "last.pt").is_file() else "Ctrl-C saved no checkpoint")


@case
def case_synth_ctrl_c_during_work(w: Workspace) -> Plan:
    args = synth_args(w.dir / "out", "--scenes", "40", "--views", "8", "--resolution", "64", "--workers", "2")
    return Plan([Step(args, "interrupt", signal=(INT, "synth", 1.5))])


@case
def case_poses_ctrl_c_during_work(w: Workspace) -> Plan:
    photos = w.photos()
    return Plan([Step(poses_args(photos, w.dir / "scene"), "interrupt", signal=(INT, "[2/6]", 0.3))],
                inputs=[photos])


@case
def case_poses_ctrl_c_during_matching(w: Workspace) -> Plan:
    """COLMAP's matcher answers Ctrl-C in the thread that called it; run in a worker thread it aborted the process
    (exit -6 and a C++ stack trace), the progress counter beside it must not change that."""
    photos = w.photos()
    return Plan([Step(poses_args(photos, w.dir / "scene", "--matcher", "exhaustive"), "interrupt",
                      signal=(INT, "[3/6]", 0.1))], inputs=[photos])


@case
def case_eval_ctrl_c_during_start_up(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(eval_args(w.fx, scene), "interrupt", signal=(INT, "", 0.4))], inputs=[scene])


@case
def case_train_kill_9_before_first_checkpoint_then_rerun(w: Workspace) -> Plan:
    data, run = w.dataset(), w.dir / "run"
    first = Step(train_args(w.fx, data, run, "--steps", "100000", "--ckpt-every", "100000"), "any",
                 signal=(KILL, "training", 1.0))
    return Plan([first, Step(train_args(w.fx, data, run), "ok")], inputs=[data])


@case
def case_poses_kill_9_then_rerun(w: Workspace) -> Plan:
    photos = w.photos()
    args = poses_args(photos, w.dir / "scene")
    return Plan([Step(args, "any", signal=(KILL, "[2/6]", 0.3)), Step(args, "ok")], inputs=[photos])


@case
def case_synth_kill_9_then_rerun(w: Workspace) -> Plan:
    args = synth_args(w.dir / "out", "--scenes", "6", "--views", "8", "--resolution", "48")
    return Plan([Step(args, "any", signal=(KILL, "synth", 1.0)), Step(args, "ok")])
