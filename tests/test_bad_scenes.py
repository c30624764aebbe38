"""Bad values in scene files, per reader: `insertnerf render` answers each with one line naming the field, no
traceback and nothing written; a dataset with bad scenes skips them and trains on the rest."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
from click.testing import CliRunner

from insertnerf_cli.cli.main import cli
from insertnerf_cli.config import ModelConfig, config_to_json
from insertnerf_cli.training.data import find_scenes
from scene_fixtures import (edit_json, known_scene, write_blender, write_colmap, write_dtu_idr, write_dtu_mvsnet,
                            write_llff, write_nerfstudio)

pytestmark = pytest.mark.usefixtures("one_thread")
NAN, INF = float("nan"), float("inf")


def angle_only(angle: Any) -> Callable[[dict[str, Any]], None]:
    """A NeRF-Synthetic file: the focal length only as camera_angle_x, here set to ``angle``."""
    def change(d: dict[str, Any]) -> None:
        for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
            d.pop(key, None)
        d["camera_angle_x"] = angle
    return change


def frame(key: str, value: Any, index: int = 0) -> Callable[[dict[str, Any]], None]:
    return lambda d: d["frames"][index].update({key: value})


def top(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    return lambda d: d.update({key: value})


# (case id, transforms change, text the one line must contain)
JSON_CASES = [
    ("angle-zero", angle_only(0), "camera_angle_x must be a number between 0 and 3.14159"),
    ("angle-negative", angle_only(-0.7), "camera_angle_x"),
    ("angle-string", angle_only("wide"), "camera_angle_x"),
    ("angle-nan", angle_only(NAN), "camera_angle_x"),
    ("angle-too-wide", angle_only(4.0), "camera_angle_x"),
    ("frame-is-a-number", lambda d: d["frames"].append(3), "must be an object"),
    ("frames-not-a-list", top("frames", {"a": 1}), "'frames' list"),
    ("file-path-number", frame("file_path", 5), "frames[0].file_path must be a relative file path"),
    ("file-path-null", frame("file_path", None), "file_path"),
    ("file-path-outside", frame("file_path", "../../etc/passwd"), "outside the scene folder"),
    ("focal-zero", frame("fl_x", 0), "frames[0].fl_x must be a number greater than 0"),
    ("focal-string", top("fl_x", "30"), "fl_x"),
    ("width-zero", top("w", 0), "w must be a number greater than 0"),
    ("height-fraction", top("h", 23.5), "h must be a positive whole number"),
    ("cx-infinite", top("cx", INF), "cx must be a finite number"),
    ("near-string", frame("near", "x"), "frames[0].near"),
    ("near-negative", frame("near", -1.0), "near=-1"),
    ("far-before-near", frame("far", 0.5), "0 < near < far"),
    ("far-infinite", frame("far", INF), "frames[0].far"),
    ("far-huge", frame("far", 1e300), "0 < near < far <= 1e+12"),
    ("focal-tiny", top("fl_x", 1e-300), "focal lengths must be at least 0.01 pixels"),
    ("position-huge", frame("transform_matrix", [[1, 0, 0, 1e200], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
     "coordinate beyond 1e+12"),
    ("pose-nan", frame("transform_matrix", [[NAN] * 4] * 4), "transform_matrix must be a 4x4 matrix"),
    ("pose-3x3", frame("transform_matrix", [[1, 0, 0]] * 3), "transform_matrix"),
    ("pose-zero", frame("transform_matrix", [[0] * 4] * 4), "not a rigid camera pose"),
    ("pose-scaled", frame("transform_matrix", [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 4], [0, 0, 0, 1]]),
     "not a rigid camera pose"),
    ("distortion-string", top("k1", "strong"), "k1"),
    ("depth-scale-zero", top("depth_unit_scale_factor", 0), "depth_unit_scale_factor"),
]


def llff_rows(change: Callable[[np.ndarray], None]) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        rows = np.load(root / "poses_bounds.npy")
        change(rows)
        np.save(root / "poses_bounds.npy", rows)
    return apply


def column(index: int, value: float, rows: slice = slice(None)) -> Callable[[np.ndarray], None]:
    return lambda a: a.__setitem__((rows, index), value)


def cam_file(old: str, new: str) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        path = root / "Cameras" / "00000000_cam.txt"
        path.write_text(path.read_text().replace(old, new, 1))
    return apply


def npz_entry(key: str, value: np.ndarray) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        arrays = dict(np.load(root / "cameras.npz"))
        arrays[key] = value
        np.savez(root / "cameras.npz", **arrays)
    return apply


def write_colmap_text(root: Path, known) -> Path:
    return write_colmap(root, known, text=True)


def colmap_camera(line: str) -> Callable[[Path], None]:
    return lambda root: (root / "sparse" / "0" / "cameras.txt").write_text(line + "\n")


# (case id, scene writer, change of the written files, text the one line must contain)
FILE_CASES = [
    ("llff-all-nan", write_llff, llff_rows(lambda a: a.fill(NAN)), "5 of 5 rows hold NaN or infinity"),
    ("llff-one-inf", write_llff, llff_rows(column(3, INF, slice(2, 3))), "row 2 first"),
    ("llff-height-zero", write_llff, llff_rows(column(4, 0.0)), "width and height must be positive"),
    ("llff-width-negative", write_llff, llff_rows(column(9, -32.0)), "width and height must be positive"),
    ("llff-focal-zero", write_llff, llff_rows(column(14, 0.0)), "focal length"),
    ("llff-near-zero", write_llff, llff_rows(column(15, 0.0)), "0 < near < far"),
    ("llff-far-before-near", write_llff, llff_rows(column(16, 0.01)), "0 < near < far"),
    ("llff-wrong-width", write_llff, lambda r: np.save(r / "poses_bounds.npy", np.zeros((5, 3))), "[N, 17]"),
    ("llff-empty-file", write_llff, lambda r: (r / "poses_bounds.npy").write_bytes(b""), "poses_bounds.npy"),
    ("colmap-focal-zero", write_colmap_text, colmap_camera("1 PINHOLE 32 24 0 30 16 12"), "focal length"),
    ("colmap-focal-nan", write_colmap_text, colmap_camera("1 PINHOLE 32 24 nan 30 16 12"), "cannot read the COLMAP model"),
    ("colmap-lens-beyond-use", write_colmap_text, colmap_camera("1 SIMPLE_RADIAL 32 24 30 16 12 1e30"),
     "leaves 100 % of the undistorted image with no source pixel"),
    ("dtu-intrinsic-nan", write_dtu_mvsnet, cam_file("intrinsic\n30", "intrinsic\nnan"), "intrinsic"),
    ("dtu-extrinsic-text", write_dtu_mvsnet, cam_file("extrinsic\n", "extrinsic\nabc "), "cannot read DTU camera"),
    ("dtu-near-negative", write_dtu_mvsnet, lambda r: (r / "Cameras" / "00000000_cam.txt").write_text(
        (r / "Cameras" / "00000000_cam.txt").read_text().rsplit("\n", 2)[0] + "\n-1 0.01\n"), "0 < near < far"),
    ("idr-world-mat-nan", write_dtu_idr, npz_entry("world_mat_0", np.full((4, 4), NAN)), "world_mat_0 must be"),
    ("idr-world-mat-shape", write_dtu_idr, npz_entry("world_mat_1", np.eye(3)), "world_mat_1 must be"),
    ("idr-world-mat-zero", write_dtu_idr, npz_entry("world_mat_0", np.zeros((4, 4))), "camera of"),
    ("idr-not-a-zip", write_dtu_idr, lambda r: (r / "cameras.npz").write_bytes(b"PK\x03\x04junk"), "cameras.npz"),
]


def one_line_refusal(tmp_path: Path, scene: Path) -> str:
    """Run `render` on a bad scene; it must stop with exactly one 'Error:' line, no traceback, no output folder."""
    out = tmp_path / "out"
    result = CliRunner().invoke(cli, ["render", str(scene), "--out", str(out), "--device", "cpu", "--frames", "1",
                                      "--resolution", "8"])  # quick, should a bad value slip through
    assert result.exit_code == 1 and isinstance(result.exception, SystemExit), result.output
    assert "Traceback" not in result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.output
    assert not out.exists()
    return lines[0]


@pytest.mark.slow
@pytest.mark.parametrize("writer", [write_nerfstudio, write_blender], ids=["nerfstudio", "blender"])
@pytest.mark.parametrize("case, change, expected", JSON_CASES, ids=[c[0] for c in JSON_CASES])
def test_bad_transforms_values_are_one_line(tmp_path: Path, writer, case: str, change, expected: str) -> None:
    root = writer(tmp_path / "scene", known_scene())
    source = root / ("transforms.json" if writer is write_nerfstudio else "transforms_train.json")
    edit_json(source, change)
    line = one_line_refusal(tmp_path, root)
    assert expected in line
    assert source.name in line or "view_000.png" in line  # names the file holding the value, or the view


@pytest.mark.slow
@pytest.mark.parametrize("case, writer, change, expected", FILE_CASES, ids=[c[0] for c in FILE_CASES])
def test_bad_camera_files_are_one_line(tmp_path: Path, case: str, writer, change, expected: str) -> None:
    root = writer(tmp_path / "scene", known_scene())
    change(root)
    assert expected in one_line_refusal(tmp_path, root)


@pytest.mark.slow
def test_dataset_skips_bad_scenes_and_trains_on_the_rest(tmp_path: Path) -> None:
    data = tmp_path / "data"
    known = known_scene(n=8)
    for name in ("good_a", "zero_angle", "number_frame", "good_b"):
        write_blender(data / name, known, test_views=(0,))
    edit_json(data / "zero_angle" / "transforms_train.json", angle_only(0))
    edit_json(data / "number_frame" / "transforms_train.json", lambda d: d["frames"].append(7))
    said: list[str] = []
    scenes = find_scenes(data, 16, said.append, show_progress=False)
    assert [s.name for s in scenes] == ["good_a", "good_b"]
    assert len(said) == 2 and all("\n" not in line for line in said)
    assert said[0].startswith("skipping number_frame: ") and "must be an object" in said[0]
    assert said[1].startswith("skipping zero_angle: ") and "camera_angle_x" in said[1]

    tiny = ModelConfig(encoder_widths=(4, 4, 4, 4), feature_dims=(4, 4, 4), nerf_width=8, appearance_width=8,
                       film_hidden=8, samples_coarse=8, samples_fine=8, aggregate_hidden=4, num_views=2)
    (tmp_path / "tiny.json").write_text(json.dumps(config_to_json(tiny)))
    result = CliRunner().invoke(cli, ["train", str(data), "--out", str(tmp_path / "run"), "--device", "cpu",
                                      "--model-config", str(tmp_path / "tiny.json"), "--steps", "1", "--rays", "16",
                                      "--resolution", "16", "--val-every", "1000"])
    assert result.exit_code == 0, result.output
    assert "skipping zero_angle" in result.output and "skipping number_frame" in result.output
    splits = json.loads((tmp_path / "run" / "splits.json").read_text())
    assert sorted(splits["train"] + splits["val"]) == ["good_a", "good_b"]


def test_dataset_of_only_bad_scenes_is_one_line(tmp_path: Path) -> None:
    data = tmp_path / "data"
    write_blender(data / "zero_angle", known_scene(), test_views=(0,))
    edit_json(data / "zero_angle" / "transforms_train.json", angle_only(0))
    result = CliRunner().invoke(cli, ["train", str(data), "--out", str(tmp_path / "run"), "--device", "cpu"])
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert "Error: no readable scene in" in result.output and "1 folder(s) could not be read" in result.output
