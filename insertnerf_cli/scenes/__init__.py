"""Scene folders: ``load_scene(path) -> Scene`` for every common format, writers, normalisation.

Formats, tried in this order (docs/formats.md): Blender ``transforms_{train,val,test}.json``, nerfstudio /
instant-ngp ``transforms.json``, LLFF ``poses_bounds.npy``, COLMAP ``sparse/0`` or ``sparse/``, DTU
``cameras.npz`` (IDR/DVR) or ``Cameras/`` + ``Rectified/`` (MVSNet). A folder of images without poses is
answered with the command that makes them.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

from insertnerf_cli.errors import SceneError, os_error_message
from insertnerf_cli.scenes import blender, colmap_model, dtu, llff, nerfstudio
from insertnerf_cli.scenes.base import Layout, Scene
from insertnerf_cli.scenes.images import IMAGE_EXTENSIONS, Distortion, find_images, read_rgb, resize
from insertnerf_cli.scenes.normalize import Similarity, normalize_scene, walk_warning
from insertnerf_cli.scenes.writers import write_blender_transforms, write_nerfstudio_transforms

__all__ = ["Distortion", "Layout", "Scene", "SceneError", "Similarity", "detect_format", "find_images",
           "load_scene", "normalize_scene", "read_rgb", "resize", "write_blender_transforms",
           "walk_warning", "write_nerfstudio_transforms", "IMAGE_EXTENSIONS"]

Reader = Callable[[Path, str, tuple[float, float, float]], Scene]


def _readers() -> dict[str, tuple[Callable[[Path], bool], Reader]]:
    """Format name -> (detector, reader), in detection order."""
    return {
        "blender": (lambda r: bool(blender.split_files(r)), lambda r, i, b: blender.read_blender(r, b)),
        "nerfstudio": (lambda r: (r / nerfstudio.FILENAME).is_file(), lambda r, i, b: nerfstudio.read_nerfstudio(r, b)),
        "llff": (lambda r: (r / llff.FILENAME).is_file(), llff.read_llff),
        "colmap": (lambda r: colmap_model.find_model(r) is not None, colmap_model.read_colmap),
        "dtu-idr": (lambda r: dtu.npz_file(r) is not None, dtu.read_idr),
        "dtu-mvsnet": (dtu.is_mvsnet, dtu.read_mvsnet),
    }


def detect_format(root: str | os.PathLike) -> str | None:
    """The name of the first format whose files are in ``root`` (see :func:`load_scene`), or None."""
    root = Path(root)
    return next((name for name, (found, _) in _readers().items() if found(root)), None)


def _no_format_error(root: Path, images: str) -> SceneError:
    """The message for a folder no reader recognises: plain images get the command that poses them."""
    for folder in (root / images, root):
        count = len(find_images(folder)) if folder.is_dir() else 0
        if count:
            return SceneError(f"{folder} holds {count} images but no camera poses; run "
                              f"`insertnerf poses {folder} --out <scene>` first, then use <scene>")
    return SceneError(f"{root} is not a scene folder: expected transforms_train.json, transforms.json, "
                      "poses_bounds.npy, sparse/0/, cameras.npz or Cameras/+Rectified/, or a folder of images")


def load_scene(path: str | os.PathLike, images: str = "images", split: str | None = None,
               background: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> Scene:
    """Read the posed images of a scene folder, detecting its format.

    Args:
        path: the scene folder (or a file in it, e.g. its transforms.json).
        images: the images sub-folder for LLFF, COLMAP and DTU (e.g. "images_4" for LLFF's quarter size).
        split: keep only this split ("train", "val", "test"); None keeps every view with ``scene.splits``.
        background: RGB in [0, 1] that transparent pixels are composited on.
    Returns:
        Scene with OpenCV cameras at the images' size, near/far per view, splits and layout.
    Raises:
        SceneError: one line saying what is wrong and what to do.
    """
    root = Path(os.path.abspath(path))
    try:
        if root.is_file():
            root = root.parent
        if not root.is_dir():
            raise SceneError(f"{path} does not exist or is not a folder")
        name = detect_format(root)
        if name is None:
            raise _no_format_error(root, images)
        scene = _readers()[name][1](root, images, tuple(float(c) for c in background))
    except OSError as err:  # e.g. an unreadable train/ folder: one line, and datasets can skip the scene
        raise SceneError(f"cannot read the scene {root}: {os_error_message(err)}") from None
    return scene.subset(scene.split(split)) if split is not None else scene
