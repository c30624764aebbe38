"""Readers on the cases users hit: no poses, escaping paths, missing or mixed images, distortion, our keys."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.scenes import SceneError, load_scene, write_blender_transforms, write_nerfstudio_transforms
from insertnerf_cli.scenes.images import undistort
from scene_fixtures import (HEIGHT, WIDTH, edit_json, look_at, pattern_image, write_blender, write_colmap,
                            write_images, write_nerfstudio)


def dot_image(xy: np.ndarray, height: int = HEIGHT, width: int = WIDTH) -> np.ndarray:
    """uint8 RGB with a 3x3 white dot on the pixel that contains image point ``xy`` (pixel (0,0) = [0,1]^2)."""
    img = np.zeros((height, width, 3), np.uint8)
    col, row = np.floor(xy).astype(int)
    img[row - 1:row + 2, col - 1:col + 2] = 255
    return img


def dot_centre(img: np.ndarray) -> np.ndarray:
    rows, cols = np.nonzero(img[..., 0] > 0.5)
    return np.array([cols.mean() + 0.5, rows.mean() + 0.5])


def test_plain_folder_says_to_run_poses(tmp_path: Path, known) -> None:
    write_images(tmp_path / "photos", known)
    with pytest.raises(SceneError, match=r"photos holds 5 images but no camera poses; run `insertnerf poses"):
        load_scene(tmp_path / "photos")
    write_images(tmp_path / "scene" / "images", known)
    with pytest.raises(SceneError, match=r"images holds 5 images but no camera poses"):
        load_scene(tmp_path / "scene")
    (tmp_path / "empty").mkdir()
    with pytest.raises(SceneError, match="is not a scene folder"):
        load_scene(tmp_path / "empty")
    with pytest.raises(SceneError, match="does not exist"):
        load_scene(tmp_path / "nowhere")


@pytest.mark.parametrize("key", ["file_path", "depth_file_path"])
def test_paths_escaping_the_scene_are_refused(tmp_path: Path, known, key: str) -> None:
    root = write_nerfstudio(tmp_path / "scene", known)
    write_images(tmp_path, known, ["outside.png"])

    def escape(data):
        for frame in data["frames"]:
            frame[key] = "../outside.png"
    edit_json(root / "transforms.json", escape)
    with pytest.raises(SceneError, match="points outside the scene folder"):
        load_scene(root)
    edit_json(root / "transforms.json", lambda d: d["frames"][0].update({key: str(tmp_path / "outside.png")}))
    with pytest.raises(SceneError, match="points outside the scene folder"):
        load_scene(root)


def test_colmap_image_name_escaping_is_refused(tmp_path: Path, known) -> None:
    import pycolmap

    root = write_colmap(tmp_path / "scene", known)
    rec = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    rec.images[1].name = "../../secret.png"
    rec.write_text(str(root / "sparse" / "0"))
    for f in (root / "sparse" / "0").glob("*.bin"):
        f.unlink()
    with pytest.raises(SceneError, match="outside the scene folder"):
        load_scene(root)


def test_missing_images_are_named(tmp_path: Path, known) -> None:
    root = write_blender(tmp_path, known)
    (root / "train" / "view_002.png").unlink()
    with pytest.raises(SceneError, match=r"1 of 5 images .* missing: .*view_002.png"):
        load_scene(root)


def test_mixed_sizes_same_aspect_are_rescaled(tmp_path: Path, known) -> None:
    root = write_nerfstudio(tmp_path, known)
    big = cv2.resize(pattern_image(1), (2 * WIDTH, 2 * HEIGHT), interpolation=cv2.INTER_NEAREST)
    cv2.imwrite(str(root / "images" / known.names[1]), big[..., ::-1])
    edit_json(root / "transforms.json", lambda d: d["frames"][1].update(
        {"w": 2 * WIDTH, "h": 2 * HEIGHT, "fl_x": 60.0, "fl_y": 60.0, "cx": WIDTH, "cy": HEIGHT}))
    scene = load_scene(root)
    assert (scene.cameras.height, scene.cameras.width) == (HEIGHT, WIDTH)  # the most common size
    torch.testing.assert_close(scene.cameras.K, known.cameras.K)
    np.testing.assert_allclose(scene.load_image(1), pattern_image(1) / 255.0, atol=1e-6)


def test_mixed_aspect_ratios_are_refused(tmp_path: Path, known) -> None:
    root = write_nerfstudio(tmp_path, known)
    cv2.imwrite(str(root / "images" / known.names[2]), np.zeros((HEIGHT, HEIGHT, 3), np.uint8))
    with pytest.raises(SceneError, match="aspect ratio"):
        load_scene(root)


def test_nerfstudio_per_frame_off_centre_intrinsics_round_trip(tmp_path: Path, known) -> None:
    K = torch.stack([intrinsics(28.0 + i, 33.0 - i, 15.0 + 0.3 * i, 12.7) for i in range(5)])
    cams = Cameras(K, known.cameras.c2w, HEIGHT, WIDTH)
    write_images(tmp_path / "images", known)
    for writer, name in ((write_nerfstudio_transforms, "transforms.json"),
                         (write_blender_transforms, "transforms_train.json")):
        root = tmp_path / name.split(".")[0]
        write_images(root / "images", known)
        writer(root / name, cams, [f"images/{n}" for n in known.names], near=1.0, far=7.0)
        scene = load_scene(root)
        torch.testing.assert_close(scene.cameras.K, K, atol=1e-9, rtol=0)
        torch.testing.assert_close(scene.cameras.c2w, cams.c2w, atol=1e-9, rtol=0)
        assert float(scene.near.min()) == 1.0 and float(scene.far.max()) == 7.0


def test_nerfstudio_applied_transform_is_undone(tmp_path: Path, known) -> None:
    root = write_nerfstudio(tmp_path, known)
    A = torch.tensor([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=torch.float64)
    edit_json(root / "transforms.json", lambda d: [d.update({"applied_transform": A[:3].tolist()})]
              + [f.update({"transform_matrix": (A @ torch.tensor(f["transform_matrix"], dtype=torch.float64)).tolist()})
                 for f in d["frames"]])
    torch.testing.assert_close(load_scene(root).cameras.c2w, known.cameras.c2w, atol=1e-9, rtol=0)


def test_nerfstudio_bounds_from_its_point_cloud(tmp_path: Path, known) -> None:
    import trimesh

    root = write_nerfstudio(tmp_path, known)
    A = torch.tensor([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=torch.float64)
    trimesh.PointCloud(known.points @ A[:3, :3].numpy().T).export(root / "sparse_pc.ply")

    def to_nerfstudio(d):
        d.update({"applied_transform": A[:3].tolist(), "ply_file_path": "sparse_pc.ply"})
        for f in d["frames"]:
            f.update({"transform_matrix": (A @ torch.tensor(f["transform_matrix"], dtype=torch.float64)).tolist()})
            f.pop("near"), f.pop("far")
    edit_json(root / "transforms.json", to_nerfstudio)
    scene = load_scene(root)
    np.testing.assert_allclose(scene.near.numpy(), known.near, atol=1e-6)  # every point is inside every view
    np.testing.assert_allclose(scene.far.numpy(), known.far, atol=1e-6)


def test_nerfstudio_splits_from_filenames(tmp_path: Path, known) -> None:
    root = write_nerfstudio(tmp_path, known)
    edit_json(root / "transforms.json", lambda d: d.update(
        {"train_filenames": [f"images/{n}" for n in known.names[:3]], "test_filenames": [f"images/{known.names[4]}"]}))
    assert load_scene(root).splits == {"train": [0, 1, 2], "test": [4]}


@pytest.mark.parametrize("model", ["OPENCV", "OPENCV_FISHEYE"])
def test_nerfstudio_distortion_is_removed_on_load(tmp_path: Path, known, model: str) -> None:
    root = write_nerfstudio(tmp_path, known)
    K = known.cameras.K[0].numpy()
    coeffs = {"k1": -0.6, "k2": 0.1, "p1": 0.002, "p2": -0.001} if model == "OPENCV" \
        else {"k1": -0.3, "k2": 0.02, "k3": 0.0, "k4": 0.0}
    point = np.array([[[0.45, -0.3, 1.0]]])  # camera frame of view 0; strong distortion for a 32-pixel image
    if model == "OPENCV":
        dist = np.array([coeffs[k] for k in ("k1", "k2", "p1", "p2")])
        xy = cv2.projectPoints(point, np.zeros(3), np.zeros(3), K - _half_shift(), dist)[0][0, 0] + 0.5
    else:
        dist = np.array([coeffs[k] for k in ("k1", "k2", "k3", "k4")])
        xy = cv2.fisheye.projectPoints(point, np.zeros(3), np.zeros(3), K - _half_shift(), dist)[0][0, 0] + 0.5
    cv2.imwrite(str(root / "images" / known.names[0]), dot_image(xy))
    edit_json(root / "transforms.json", lambda d: d.update({"camera_model": model, **coeffs}))
    scene = load_scene(root)
    assert scene.distortion is not None and scene.distortion[0].model == ("opencv" if model == "OPENCV" else "fisheye")
    pinhole = K[:2, :2] @ point[0, 0, :2] + K[:2, 2]
    assert np.abs(xy - pinhole).max() > 1.5  # the distortion really moves the dot
    np.testing.assert_allclose(dot_centre(scene.load_image(0)), pinhole, atol=0.75)


def _half_shift() -> np.ndarray:
    """Subtract from our K to get OpenCV's (pixel centres at integers)."""
    return np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])


def test_nerfstudio_unsupported_cameras_are_refused(tmp_path: Path, known) -> None:
    root = write_nerfstudio(tmp_path, known)
    edit_json(root / "transforms.json", lambda d: d.update({"camera_model": "EQUIRECTANGULAR"}))
    with pytest.raises(SceneError, match="not a pinhole camera"):
        load_scene(root)
    edit_json(root / "transforms.json", lambda d: d.update({"camera_model": "OPENCV", "k4": 0.1}))
    with pytest.raises(SceneError, match="k4"):
        load_scene(root)


def test_colmap_simple_radial_is_undistorted_and_fov_refused(tmp_path: Path, known) -> None:
    import pycolmap

    root = write_colmap(tmp_path, known)
    model = root / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(model))
    cam = pycolmap.Camera(camera_id=1, model="SIMPLE_RADIAL", width=WIDTH, height=HEIGHT,
                          params=[30.0, WIDTH / 2, HEIGHT / 2, -0.6])
    rec.cameras[1] = cam
    rec.write_binary(str(model))
    point = np.array([0.45, -0.3, 1.0])
    xy = cam.img_from_cam(point[None])[0]  # COLMAP's own distorted projection
    cv2.imwrite(str(root / "images" / known.names[0]), dot_image(xy))
    scene = load_scene(root)
    pinhole = 30.0 * point[:2] + np.array([WIDTH / 2, HEIGHT / 2])
    assert np.abs(xy - pinhole).max() > 1.5
    np.testing.assert_allclose(dot_centre(scene.load_image(0)), pinhole, atol=0.75)
    rec.cameras[1] = pycolmap.Camera(camera_id=1, model="FOV", width=WIDTH, height=HEIGHT,
                                     params=[30.0, 30.0, 16.0, 12.0, 0.1])
    rec.write_binary(str(model))
    with pytest.raises(SceneError, match="image_undistorter"):
        load_scene(root)


def test_pincushion_is_undistorted_onto_a_zoomed_camera_without_blank_corners(tmp_path: Path, known) -> None:
    """COLMAP's default SIMPLE_RADIAL with k > 0: keeping K would leave black corners that a reference view lends
    as black surfaces; the loaded camera zooms just enough that every pixel has a source, and points land on it."""
    import pycolmap

    root = write_colmap(tmp_path, known)
    model = root / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(model))
    cam = pycolmap.Camera(camera_id=1, model="SIMPLE_RADIAL", width=WIDTH, height=HEIGHT,
                          params=[30.0, WIDTH / 2, HEIGHT / 2, 0.3])
    rec.cameras[1] = cam
    rec.write_binary(str(model))
    point = np.array([0.3, -0.2, 1.0])
    xy = cam.img_from_cam(point[None])[0]
    cv2.imwrite(str(root / "images" / known.names[0]), dot_image(xy))
    cv2.imwrite(str(root / "images" / known.names[1]), np.full((HEIGHT, WIDTH, 3), 128, np.uint8))
    scene = load_scene(root)
    zoom = scene.distortion[0].zoom
    K = scene.cameras.K[0].numpy()
    assert 1.02 < zoom < 1.5 and np.isclose(K[0, 0], 30.0 * zoom) and np.isclose(K[0, 2], WIDTH / 2)
    np.testing.assert_allclose(dot_centre(scene.load_image(0)), K[:2, :2] @ point[:2] + K[:2, 2], atol=0.75)
    grey = np.full((HEIGHT, WIDTH, 3), 0.5, np.float32)
    assert scene.load_image(1).min() > 0.45  # no black corner
    photo_K = np.array([[30.0, 0, WIDTH / 2], [0, 30.0, HEIGHT / 2], [0, 0, 1]])
    assert undistort(grey, photo_K, replace(scene.distortion[1], zoom=1.0)).min() < 0.05  # K kept: black corners


def test_our_keys_depth_layout_and_bounds_are_read(tmp_path: Path, known) -> None:
    write_images(tmp_path / "rgb", known)
    write_images(tmp_path / "depth", known)
    write_blender_transforms(tmp_path / "transforms_train.json", known.cameras, [f"rgb/{n}" for n in known.names],
                             near=0.5, far=9.0, extra={"layout": "forward", "depth_unit_scale_factor": 0.004},
                             frame_extras=[{"depth_file_path": f"depth/{n}"} for n in known.names])
    scene = load_scene(tmp_path)
    assert scene.layout == "forward" and scene.depth_scale == 0.004
    assert scene.depth_paths == [tmp_path / "depth" / n for n in known.names]
    assert scene.near.tolist() == [0.5] * 5 and scene.far.tolist() == [9.0] * 5
    edit_json(tmp_path / "transforms_train.json", lambda d: d["frames"][0].pop("depth_file_path"))
    with pytest.raises(SceneError, match="4 of 5 frames have 'depth_file_path'"):
        load_scene(tmp_path)


def test_blender_without_bounds_uses_nerf_synthetic_ratios(tmp_path: Path, known) -> None:
    root = write_blender(tmp_path, known)
    for split in ("train", "test"):
        edit_json(root / f"transforms_{split}.json", lambda d: [f.pop("near") or f.pop("far") for f in d["frames"]])
    scene = load_scene(root)
    torch.testing.assert_close(scene.near, torch.full((5,), 2.0, dtype=torch.float64))  # cameras at 4: 2 / 6
    torch.testing.assert_close(scene.far, torch.full((5,), 6.0, dtype=torch.float64))


def test_forward_facing_capture_is_detected(tmp_path: Path, known) -> None:
    poses = [look_at(np.array([x, y, 0.0]), np.array([0.1 * x, 0.1 * y, 5.0]),
                     np.array([0.0, -1.0, 0.0])) for x in (-0.5, 0.5) for y in (-0.3, 0.3)]
    cams = Cameras(known.cameras.K[:4], torch.from_numpy(np.stack(poses)), HEIGHT, WIDTH)
    write_images(tmp_path / "images", known)
    write_nerfstudio_transforms(tmp_path / "transforms.json", cams, [f"images/{n}" for n in known.names[:4]])
    scene = load_scene(tmp_path)
    assert scene.layout == "forward"
    assert bool((scene.near > 0).all() and (scene.far > 4 * scene.near - 1e-9).all())


def test_broken_files_give_one_line(tmp_path: Path, known) -> None:
    root = write_nerfstudio(tmp_path, known)
    (root / "transforms.json").write_text("{not json")
    with pytest.raises(SceneError, match="cannot read"):
        load_scene(root)
    write_nerfstudio(root, known)
    edit_json(root / "transforms.json", lambda d: d["frames"][0].update({"transform_matrix": [[float("nan")] * 4] * 4}))
    with pytest.raises(SceneError, match="transform_matrix must be a 4x4 matrix of finite numbers"):
        load_scene(root)
    edit_json(root / "transforms.json", lambda d: d["frames"][0].update({"transform_matrix": [[2.0, 0, 0, 0]] * 4}))
    with pytest.raises(SceneError, match="rotation"):
        load_scene(root)
