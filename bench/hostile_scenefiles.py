"""Cases of bench/hostile.py for damaged scene files, odd photo names, WebP photos and the package's bundled
weights (issue 29).

Scenes in LLFF, DTU (IDR) and COLMAP formats are written by tests/scene_fixtures.py and then damaged the way a
hostile user found: a .npy header that no longer parses, flipped bytes in cameras.npz, a non-UTF-8 image name in
images.bin, cameras.bin and points3D.bin cut short. Each must be one short error, never a traceback. Photos with
non-UTF-8 names or in WebP must be posed (exit 0) with nothing written inside the photo folder. No command may
write or remove anything in the package's weights folder, whatever --out says.
"""
from __future__ import annotations

import hashlib
import os
import struct
import sys
from pathlib import Path
from typing import Callable

import cv2
from hostile_finetune import finetune_args
from hostile_kit import (Plan, Step, Workspace, case, eval_args, poses_args, render_args, synth_args,
                         train_args)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import scene_fixtures  # noqa: E402

WEIGHTS = ROOT / "insertnerf_cli" / "weights"  # the launcher runs this checkout's code (PYTHONPATH)


def _damaged(w: Workspace, writer, rel: str, damage) -> Path:
    root = writer(w.dir / "scene", scene_fixtures.known_scene())
    path = root / rel
    path.write_bytes(damage(path.read_bytes()))
    return root


def _render_refused(w: Workspace, scene: Path) -> Plan:
    return Plan([Step(render_args(w.fx, scene, w.dir / "out"))], inputs=[scene])


@case
def case_render_llff_npy_with_damaged_header(w: Workspace) -> Plan:
    def unclose(data: bytes) -> bytes:
        at = data.index(b"'shape'") + 10
        return data[:at] + b"(" + data[at + 1:]  # numpy's own parser raised tokenize.TokenError
    return _render_refused(w, _damaged(w, scene_fixtures.write_llff, "poses_bounds.npy", unclose))


@case
def case_render_dtu_npz_with_flipped_bytes(w: Workspace) -> Plan:
    def flip(data: bytes) -> bytes:
        return data[:200] + bytes(b ^ 0x5A for b in data[200:260]) + data[260:]
    return _render_refused(w, _damaged(w, scene_fixtures.write_dtu_idr, "cameras.npz", flip))


@case
def case_eval_dtu_compressed_npz_with_flipped_bytes(w: Workspace) -> Plan:
    import numpy as np

    root = scene_fixtures.write_dtu_idr(w.dir / "scene", scene_fixtures.known_scene())
    np.savez_compressed(root / "cameras.npz", **dict(np.load(root / "cameras.npz")))
    data = (root / "cameras.npz").read_bytes()
    (root / "cameras.npz").write_bytes(data[:60] + bytes(b ^ 0xFF for b in data[60:90]) + data[90:])  # zlib.error
    return Plan([Step(eval_args(w.fx, root))], inputs=[root])


@case
def case_render_colmap_images_bin_name_not_utf8(w: Workspace) -> Plan:
    return _render_refused(w, _damaged(w, scene_fixtures.write_colmap, "sparse/0/images.bin",
                                       lambda d: d.replace(b"view_001", b"view\xe9001", 1)))


@case
def case_render_colmap_cameras_bin_cut_short(w: Workspace) -> Plan:
    return _render_refused(w, _damaged(w, scene_fixtures.write_colmap, "sparse/0/cameras.bin", lambda d: d[:54]))


@case
def case_render_colmap_points3d_bin_cut_short(w: Workspace) -> Plan:
    return _render_refused(w, _damaged(w, scene_fixtures.write_colmap, "sparse/0/points3D.bin",
                                       lambda d: d[: int(len(d) * 0.85)]))


@case
def case_eval_colmap_points3d_bin_huge_count(w: Workspace) -> Plan:
    scene = _damaged(w, scene_fixtures.write_colmap, "sparse/0/points3D.bin",
                     lambda d: struct.pack("<Q", 2**40) + d[8:])  # pycolmap allocated without bound
    return Plan([Step(eval_args(w.fx, scene))], inputs=[scene])


def _posed(out: Path, count: int) -> str | None:
    from insertnerf_cli.scenes import SceneError, load_scene

    try:
        views = len(load_scene(out))
    except SceneError as err:
        return f"the posed scene does not load: {err}"
    return None if views == count else f"{views} posed views, expected {count}"


@case
def case_poses_photo_names_not_utf8(w: Workspace) -> Plan:
    photos, out = w.photos(), w.dir / "scene"
    for path in sorted(photos.iterdir())[::3]:  # every third photo gets a Latin-1 name
        os.rename(path, os.path.join(os.fsencode(photos), os.fsencode(path.stem) + b"_caf\xe9" +
                                     os.fsencode(path.suffix)))
    return Plan([Step(poses_args(photos, out), "ok")], inputs=[photos], check=lambda: _posed(out, 16))


@case
def case_poses_half_the_photos_lossless_webp(w: Workspace) -> Plan:
    photos, out = w.photos(), w.dir / "scene"
    for path in sorted(photos.iterdir())[::2]:  # half the photos become (lossless) WebP
        ok, data = cv2.imencode(".webp", cv2.imread(str(path)), [cv2.IMWRITE_WEBP_QUALITY, 101])
        path.with_suffix(".webp").write_bytes(data.tobytes())
        path.unlink()
    return Plan([Step(poses_args(photos, out), "ok")], inputs=[photos], check=lambda: _posed(out, 16))


@case
def case_render_photo_folder_with_webp_and_odd_names(w: Workspace) -> Plan:
    photos, out = w.photos(), w.dir / "out"
    paths = sorted(photos.iterdir())
    ok, data = cv2.imencode(".webp", cv2.imread(str(paths[0])), [cv2.IMWRITE_WEBP_QUALITY, 101])
    paths[0].with_suffix(".webp").write_bytes(data.tobytes())
    paths[0].unlink()
    os.rename(paths[1], os.path.join(os.fsencode(photos), b"\xff\xfe.png"))
    return Plan([Step(render_args(w.fx, photos, out), "ok")], inputs=[photos])


# ------------------------------------------------------------------------------------- bundled weights
def _weights_unchanged() -> Callable[[], str | None]:
    before = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(WEIGHTS.iterdir())}

    def check() -> str | None:
        after = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(WEIGHTS.iterdir())}
        return None if after == before else f"the bundled weights folder changed: {sorted(set(after) ^ set(before))}"

    return check


def _weights_case(args: list[str], inputs: list[Path]) -> Plan:
    return Plan([Step(args)], inputs=inputs, check=_weights_unchanged())


@case
def case_finetune_out_is_a_bundled_weight_overwrite(w: Workspace) -> Plan:
    scene = w.scene()
    return _weights_case(finetune_args(w.fx, scene, WEIGHTS / "insertnerf.pt", "--overwrite"), [scene])


@case
def case_finetune_out_is_the_default_bundled_weight_overwrite(w: Workspace) -> Plan:
    scene = w.scene()
    return _weights_case(finetune_args(w.fx, scene, WEIGHTS / "insertnerf-fast.pt", "--overwrite"), [scene])


@case
def case_render_out_is_the_bundled_weights_folder_overwrite(w: Workspace) -> Plan:
    scene = w.scene()
    return _weights_case(render_args(w.fx, scene, WEIGHTS, "--overwrite"), [scene])


@case
def case_train_out_inside_the_bundled_weights_folder(w: Workspace) -> Plan:
    data = w.dataset()
    return _weights_case(train_args(w.fx, data, WEIGHTS / "run"), [data])


@case
def case_eval_json_inside_the_bundled_weights_folder(w: Workspace) -> Plan:
    scene = w.scene()
    return _weights_case(eval_args(w.fx, scene, "--json", str(WEIGHTS / "scores.json")), [scene])


@case
def case_synth_out_inside_the_bundled_weights_folder(w: Workspace) -> Plan:
    return _weights_case(synth_args(WEIGHTS / "data"), [])


@case
def case_poses_out_is_the_bundled_weights_folder_overwrite(w: Workspace) -> Plan:
    photos = w.photos()
    return _weights_case(poses_args(photos, WEIGHTS, "--overwrite"), [photos])

