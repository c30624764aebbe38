"""Every reader on one known scene written in its format: cameras back to 1e-6, bounds, images, splits."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import torch

from insertnerf_cli.scenes import Scene, load_scene
from scene_fixtures import (KnownScene, write_blender, write_colmap, write_dtu_idr,
                            write_dtu_mvsnet, write_llff, write_nerfstudio)

TOL = 1e-6

WRITERS: dict[str, Callable[[Path, KnownScene], Path]] = {
    "blender": write_blender,
    "nerfstudio": write_nerfstudio,
    "llff": write_llff,
    "colmap-bin": lambda root, known: write_colmap(root, known, text=False),
    "colmap-txt": lambda root, known: write_colmap(root, known, text=True),
    "dtu-mvsnet": write_dtu_mvsnet,
    "dtu-idr": write_dtu_idr,
}
FORMAT_NAMES = {"colmap-bin": "colmap", "colmap-txt": "colmap", "dtu-mvsnet": "dtu", "dtu-idr": "dtu"}


def order_by_name(scene: Scene, known: KnownScene) -> list[int]:
    """Index into ``known`` of each scene view, matched by the number in the file name (formats rename files)."""
    numbers = ["".join(ch for ch in Path(name).stem if ch.isdigit()) for name in scene.names]
    offset = 1 if scene.names[0].split("/")[-1].startswith("rect_") else 0  # DTU numbers views from 1
    return [int(n[: 3 if offset else None]) - offset for n in numbers]


def assert_matches(scene: Scene, known: KnownScene, bounds: bool = True) -> None:
    order = order_by_name(scene, known)
    assert sorted(order) == list(range(len(known.names)))
    ref = known.cameras.subset(order)
    assert (scene.cameras.height, scene.cameras.width) == (ref.height, ref.width)
    torch.testing.assert_close(scene.cameras.c2w, ref.c2w, atol=TOL, rtol=0)
    torch.testing.assert_close(scene.cameras.K, ref.K, atol=TOL, rtol=0)
    if bounds:
        np.testing.assert_allclose(scene.near.numpy(), known.near[order], atol=TOL)
        np.testing.assert_allclose(scene.far.numpy(), known.far[order], atol=TOL)


@pytest.mark.parametrize("fmt", list(WRITERS))
def test_known_scene_round_trips(tmp_path: Path, known: KnownScene, fmt: str) -> None:
    scene = load_scene(WRITERS[fmt](tmp_path, known))
    assert scene.format == FORMAT_NAMES.get(fmt, fmt)
    assert scene.layout == "object"
    assert_matches(scene, known, bounds=fmt != "dtu-idr")
    order = order_by_name(scene, known)
    np.testing.assert_allclose(scene.load_image(0), known.images[order[0]] / 255.0, atol=1e-6)


def test_idr_bounds_enclose_the_unit_sphere(tmp_path: Path, known: KnownScene) -> None:
    scene = load_scene(write_dtu_idr(tmp_path, known, scale=3.0))
    assert_matches(scene, known, bounds=False)  # scale_mat undone: back in the known world
    torch.testing.assert_close(scene.near, torch.full((5,), 3.0, dtype=torch.float64))
    torch.testing.assert_close(scene.far, torch.full((5,), 5.0, dtype=torch.float64))


def test_llff_and_colmap_agree(tmp_path: Path, known: KnownScene) -> None:
    llff = load_scene(write_llff(tmp_path / "llff", known))
    colmap = load_scene(write_colmap(tmp_path / "colmap", known))
    assert llff.names == colmap.names
    torch.testing.assert_close(llff.cameras.c2w, colmap.cameras.c2w, atol=TOL, rtol=0)
    torch.testing.assert_close(llff.cameras.K, colmap.cameras.K, atol=TOL, rtol=0)
    torch.testing.assert_close(llff.near, colmap.near, atol=TOL, rtol=0)  # LLFF's rule from COLMAP's points
    torch.testing.assert_close(llff.far, colmap.far, atol=TOL, rtol=0)


def test_llff_downscaled_folder_scales_K(tmp_path: Path, known: KnownScene) -> None:
    scene = load_scene(write_llff(tmp_path, known, factor=2), images="images_2")
    assert (scene.cameras.height, scene.cameras.width) == (12, 16)
    torch.testing.assert_close(scene.cameras.K, known.cameras.rescale(12, 16).K)
    torch.testing.assert_close(scene.cameras.c2w, known.cameras.c2w)


def test_dtu_quarter_size_cameras_are_scaled(tmp_path: Path, known: KnownScene) -> None:
    write_dtu_mvsnet(tmp_path, known, k_factor=4)
    scene = load_scene(tmp_path)
    assert_matches(scene, known)
    assert all("_3_r5000" in name for name in scene.names)  # light 3 chosen among two lightings


def test_blender_splits_and_split_option(tmp_path: Path, known: KnownScene) -> None:
    write_blender(tmp_path, known, test_views=(1, 3))
    scene = load_scene(tmp_path)
    assert scene.splits == {"train": [0, 1, 2], "test": [3, 4]}
    assert [Path(scene.names[i]).stem for i in scene.splits["test"]] == ["view_001", "view_003"]
    test = load_scene(tmp_path, split="test")
    assert len(test) == 2 and test.splits == {"test": [0, 1]}
    torch.testing.assert_close(test.cameras.c2w, known.cameras.c2w[[1, 3]])


def test_scene_file_may_be_given(tmp_path: Path, known: KnownScene) -> None:
    write_nerfstudio(tmp_path, known)
    assert len(load_scene(tmp_path / "transforms.json")) == len(known.names)


def test_load_sizes_rescales_images_and_cameras_rescale_alike(tmp_path: Path, known: KnownScene) -> None:
    scene = load_scene(write_nerfstudio(tmp_path, known))
    images, = scene.load_sizes([2, 0], [(12, 16)])
    assert images.shape == (2, 12, 16, 3) and images.dtype == torch.float32
    torch.testing.assert_close(scene.cameras.subset([2, 0]).rescale(12, 16).K, known.cameras.rescale(12, 16).K[[2, 0]])
    assert scene.size_for(16) == (12, 16)
