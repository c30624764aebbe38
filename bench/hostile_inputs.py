"""Cases of bench/hostile.py about INPUTS: scene values never to be trusted, options, odd folders and files,
and files that are not checkpoints. Each expects a short error and exit 1-125 unless it says otherwise.
"""
from __future__ import annotations

import json
import pickle
import shutil
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from hostile_kit import TINY_MODEL, Plan, Step, Workspace, case, edit_transforms, eval_args, poses_args, render_args, \
    synth_args, train_args


# ---------------------------------------------------------------- scene values never to be trusted
def _bad_transforms(w: Workspace, change: Callable[[dict], None], command: str = "render") -> Plan:
    scene = w.scene()
    edit_transforms(scene, change)
    args = render_args(w.fx, scene, w.dir / "out") if command == "render" else eval_args(w.fx, scene)
    return Plan([Step(args)], inputs=[scene])


def _set_frame(index: int, key: str, value: object) -> Callable[[dict], None]:
    return lambda meta: meta["frames"][index].__setitem__(key, value)


def _angle(value: object) -> Callable[[dict], None]:
    """NeRF-Synthetic style: the focal length only from camera_angle_x (synth also writes fl_x, which wins)."""
    def change(meta: dict) -> None:
        for key in ("fl_x", "fl_y", "cx", "cy"):
            meta.pop(key, None)
        meta["camera_angle_x"] = value
    return change


@case
def case_render_camera_angle_zero(w: Workspace) -> Plan:
    return _bad_transforms(w, _angle(0))


@case
def case_render_camera_angle_string(w: Workspace) -> Plan:
    return _bad_transforms(w, _angle("wide"))


@case
def case_render_camera_angle_negative(w: Workspace) -> Plan:
    return _bad_transforms(w, _angle(-0.7))


@case
def case_eval_camera_angle_nan(w: Workspace) -> Plan:
    return _bad_transforms(w, _angle(float("nan")), "eval")


@case
def case_eval_frame_entry_is_a_number(w: Workspace) -> Plan:
    return _bad_transforms(w, lambda meta: meta["frames"].append(5), "eval")


@case
def case_render_focal_length_negative(w: Workspace) -> Plan:
    return _bad_transforms(w, lambda meta: meta.update(fl_x=-46.0, fl_y=-46.0))


@case
def case_render_file_path_not_a_string(w: Workspace) -> Plan:
    return _bad_transforms(w, _set_frame(0, "file_path", 12))


@case
def case_render_transform_matrix_nan(w: Workspace) -> Plan:
    return _bad_transforms(w, _set_frame(0, "transform_matrix", [[float("nan")] * 4] * 4))


@case
def case_eval_frames_not_a_list(w: Workspace) -> Plan:
    return _bad_transforms(w, lambda meta: meta.__setitem__("frames", {"a": 1}), "eval")


@case
def case_render_missing_image(w: Workspace) -> Plan:
    scene = w.scene()
    (scene / "train" / "r_002.png").unlink()
    return Plan([Step(render_args(w.fx, scene, w.dir / "out"))], inputs=[scene])


@case
def case_render_file_path_escapes_the_scene(w: Workspace) -> Plan:
    scene = w.scene()
    outside = Path(shutil.copy(scene / "train" / "r_000.png", w.dir / "outside.png"))
    edit_transforms(scene, _set_frame(0, "file_path", "../outside"))
    return Plan([Step(render_args(w.fx, scene, w.dir / "out"))], inputs=[scene], foreign=[outside])


@case
def case_eval_image_is_not_an_image(w: Workspace) -> Plan:
    scene = w.scene()
    (scene / "test" / "r_000.png").write_text("not a png\n")
    return Plan([Step(eval_args(w.fx, scene))], inputs=[scene])


def _llff(w: Workspace, rows: np.ndarray) -> Path:
    """An LLFF scene: poses_bounds.npy ``rows`` [N, 17] and N images."""
    scene = w.dir / "llff"
    (scene / "images").mkdir(parents=True)
    for i, path in enumerate(sorted((w.fx.data / "scene_00000" / "train").glob("*.png"))[:len(rows)]):
        shutil.copy(path, scene / "images" / f"{i:03d}.png")
    np.save(scene / "poses_bounds.npy", rows)
    return scene


def _llff_rows(n: int, height: float, width: float) -> np.ndarray:
    rows = []
    for i in range(n):
        pose = np.concatenate([np.eye(3), [[0.1 * i], [0.0], [0.0]], [[height], [width], [30.0]]], axis=1)
        rows.append(np.concatenate([pose.reshape(15), [1.0, 5.0]]))
    return np.array(rows)


@case
def case_eval_llff_poses_all_nan(w: Workspace) -> Plan:
    scene = _llff(w, np.full((6, 17), np.nan))
    return Plan([Step(eval_args(w.fx, scene))], inputs=[scene])


@case
def case_render_llff_height_width_zero(w: Workspace) -> Plan:
    scene = _llff(w, _llff_rows(6, 0.0, 0.0))
    return Plan([Step(render_args(w.fx, scene, w.dir / "out"))], inputs=[scene])


@case
def case_render_llff_wrong_shape(w: Workspace) -> Plan:
    scene = _llff(w, np.ones((6, 9)))
    return Plan([Step(render_args(w.fx, scene, w.dir / "out"))], inputs=[scene])


@case
def case_train_dataset_with_one_bad_scene(w: Workspace) -> Plan:
    """One scene with camera_angle_x 0 is skipped with a warning; the others train."""
    data = w.dataset()
    edit_transforms(data / "scene_00002", _angle(0))
    return Plan([Step(train_args(w.fx, data, w.dir / "run"), "ok")], inputs=[data])


@case
def case_train_dataset_with_one_broken_json(w: Workspace) -> Plan:
    data = w.dataset()
    (data / "scene_00001" / "transforms_train.json").write_text('{"frames": [')
    return Plan([Step(train_args(w.fx, data, w.dir / "run"), "ok")], inputs=[data])


# ---------------------------------------------------------------- options
@case
def case_render_fps_nan(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(render_args(w.fx, scene, w.dir / "out", "--fps", "nan"))], inputs=[scene])


@case
def case_render_fps_inf(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(render_args(w.fx, scene, w.dir / "out", "--fps", "inf"))], inputs=[scene])


@case
def case_render_frames_zero(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(render_args(w.fx, scene, w.dir / "out", "--frames", "0"))], inputs=[scene])


@case
def case_eval_views_zero(w: Workspace) -> Plan:
    scene = w.scene()
    return Plan([Step(eval_args(w.fx, scene, "--views", "0"))], inputs=[scene])


@case
def case_train_model_config_negative_width(w: Workspace) -> Plan:
    data, config = w.dataset(), w.file("bad.json", json.dumps(dict(TINY_MODEL, nerf_width=-8)))
    return Plan([Step(train_args(w.fx, data, w.dir / "run", "--model-config", str(config)))], inputs=[data])


@case
def case_train_model_config_not_json(w: Workspace) -> Plan:
    data, config = w.dataset(), w.file("bad.json", "nerf_width: 8\n")
    return Plan([Step(train_args(w.fx, data, w.dir / "run", "--model-config", str(config)))], inputs=[data])


@case
def case_train_steps_zero_and_lr_nan(w: Workspace) -> Plan:
    data = w.dataset()
    return Plan([Step(train_args(w.fx, data, w.dir / "run", "--steps", "0")),
                 Step(train_args(w.fx, data, w.dir / "run2", "--lr", "nan"))], inputs=[data])


@case
def case_synth_views_one(w: Workspace) -> Plan:
    return Plan([Step(synth_args(w.dir / "out", "--views", "1"))])


@case
def case_synth_test_views_all(w: Workspace) -> Plan:
    return Plan([Step(synth_args(w.dir / "out", "--test-views", "4"))])


@case
def case_poses_max_image_size_zero(w: Workspace) -> Plan:
    photos = w.photos(count=4)
    return Plan([Step(poses_args(photos, w.dir / "scene", "--max-image-size", "0"))], inputs=[photos])


# ---------------------------------------------------------------- odd folders and files
@case
def case_render_empty_folder(w: Workspace) -> Plan:
    (w.dir / "empty").mkdir()
    return Plan([Step(render_args(w.fx, w.dir / "empty", w.dir / "out"))])


@case
def case_eval_empty_folder(w: Workspace) -> Plan:
    (w.dir / "empty").mkdir()
    return Plan([Step(eval_args(w.fx, w.dir / "empty"))])


@case
def case_train_empty_folder(w: Workspace) -> Plan:
    (w.dir / "empty").mkdir()
    return Plan([Step(train_args(w.fx, w.dir / "empty", w.dir / "run"))])


@case
def case_poses_empty_folder(w: Workspace) -> Plan:
    (w.dir / "empty").mkdir()
    return Plan([Step(poses_args(w.dir / "empty", w.dir / "scene"))])


def _not_images(w: Workspace) -> Path:
    for i in range(4):
        w.file(f"docs/page_{i}.txt", f"page {i}\n")
    w.file("docs/fake.png", "not a png\n")
    return w.dir / "docs"


@case
def case_poses_folder_of_non_images(w: Workspace) -> Plan:
    docs = _not_images(w)
    return Plan([Step(poses_args(docs, w.dir / "scene"))], inputs=[docs])


@case
def case_render_folder_of_non_images_leaves_nothing(w: Workspace) -> Plan:
    docs, out = _not_images(w), w.dir / "out"
    return Plan([Step(render_args(w.fx, docs, out))], inputs=[docs], check=lambda: _empty_or_absent(out))


@case
def case_render_unposable_photos_leaves_nothing(w: Workspace) -> Plan:
    """Three tiny photos COLMAP cannot pose: a clear error, and no render_config.json left in --out."""
    photos, out = w.dir / "photos", w.dir / "out"
    photos.mkdir()
    for i, path in enumerate(sorted((w.fx.data / "scene_00000" / "train").glob("*.png"))[:3]):
        shutil.copy(path, photos / f"p{i}.png")
    return Plan([Step(render_args(w.fx, photos, out))], inputs=[photos], check=lambda: _empty_or_absent(out))


def _empty_or_absent(folder: Path) -> str | None:
    left = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
    return f"a failed run left {left} in {folder.name}/" if left else None


@case
def case_poses_mixed_image_sizes(w: Workspace) -> Plan:
    photos = w.photos(count=6)
    small = sorted(photos.iterdir())[0]
    cv2.imwrite(str(small), cv2.resize(cv2.imread(str(small)), (120, 100)))
    return Plan([Step(poses_args(photos, w.dir / "scene"))], inputs=[photos])


@case
def case_poses_three_tiny_photos(w: Workspace) -> Plan:
    photos = w.dir / "photos"
    photos.mkdir()
    for i, path in enumerate(sorted((w.fx.data / "scene_00000" / "train").glob("*.png"))[:3]):
        shutil.copy(path, photos / f"p{i}.png")
    return Plan([Step(poses_args(photos, w.dir / "scene"))], inputs=[photos])


@case
def case_poses_webp_photos(w: Workspace) -> Plan:
    """.webp is accepted by the docs: either poses work or one clear line says why not."""
    photos = w.dir / "photos"
    photos.mkdir()
    for path in sorted(w.fx.room.iterdir()):
        cv2.imwrite(str(photos / f"{path.stem}.webp"), cv2.imread(str(path)), [cv2.IMWRITE_WEBP_QUALITY, 95])
    return Plan([Step(poses_args(photos, w.dir / "scene"), "any")], inputs=[photos])


# ---------------------------------------------------------------- checkpoints
def _bad_checkpoint(w: Workspace, data: bytes) -> Path:
    path = w.dir / "bad.pt"
    path.write_bytes(data)
    return path


@case
def case_render_truncated_checkpoint(w: Workspace) -> Plan:
    scene, whole = w.scene(), w.fx.ckpt.read_bytes()
    bad = _bad_checkpoint(w, whole[: len(whole) // 2])
    return Plan([Step(render_args(w.fx, scene, w.dir / "out", "--checkpoint", str(bad)))], inputs=[scene, bad])


@case
def case_eval_checkpoint_is_an_image(w: Workspace) -> Plan:
    scene = w.scene()
    bad = _bad_checkpoint(w, (scene / "train" / "r_000.png").read_bytes())
    return Plan([Step(eval_args(w.fx, scene, "--checkpoint", str(bad)))], inputs=[scene, bad])


@case
def case_render_checkpoint_is_a_pickle_of_other_things(w: Workspace) -> Plan:
    scene = w.scene()
    bad = _bad_checkpoint(w, pickle.dumps({"model": [1, 2, 3], "note": "not ours"}))
    return Plan([Step(render_args(w.fx, scene, w.dir / "out", "--checkpoint", str(bad)))], inputs=[scene, bad])


@case
def case_train_resume_from_corrupt_checkpoint(w: Workspace) -> Plan:
    data, run = w.dataset(), Path(shutil.copytree(w.fx.run, w.dir / "run"))
    last = run / "checkpoints" / "last.pt"
    last.write_bytes(last.read_bytes()[:1000])
    return Plan([Step(train_args(w.fx, data, run, "--resume", "--steps", "4"))], inputs=[data],
                foreign=[run / "checkpoints"])


@case
def case_train_model_config_is_a_checkpoint(w: Workspace) -> Plan:
    data = w.dataset()
    return Plan([Step(train_args(w.fx, data, w.dir / "run", "--model-config", str(w.fx.ckpt)))], inputs=[data])