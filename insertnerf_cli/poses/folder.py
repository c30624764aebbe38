"""Files around `insertnerf poses` (no pycolmap here): checking the input images and the output folder, the
temporary folder moved into place, and the scene files written from a finished model.

The scene is built in ``.<OUT>.partial-<pid>-*`` beside the output. On success it becomes the output, or, when
the output exists (--overwrite), the earlier outputs insertnerf recorded there are removed and the new files
moved in: a user's own files in the output folder stay. A partial folder whose process is gone (kill -9) is
removed by the next run.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.errors import SceneError, UserError
from insertnerf_cli.files.atomic import process_alive
from insertnerf_cli.files.outdir import (
    OutputRecord,
    check_output as check_output_path,
    holds_files,
    move_into,
    record_tree,
)
from insertnerf_cli.poses.preview import write_camera_frustums, write_point_cloud
from insertnerf_cli.scenes.images import IMAGE_EXTENSIONS, exif_orientation, find_images, read_rgb
from insertnerf_cli.scenes.writers import write_nerfstudio_transforms

MIN_IMAGES = 3
# LLFF's habit: near/far are the 0.1 and 99.9 percentiles of the depths of the points an image sees.
DEPTH_PERCENTILES = (0.1, 99.9)
OWNER = "poses"  # the name of its list in an output record (outdir.py)
_PARTIAL = ".partial-"
# Formats OpenCV decodes (so scenes and `poses` accept them) but COLMAP's own image reader does not.
COLMAP_UNDECODABLE = (".webp",)
# What `poses` wrote before outputs were recorded: the only names --overwrite removes from such a folder.
LEGACY_OUTPUTS = ("transforms.json", "sparse.ply", "cameras.ply", "images/*", "images/", "colmap/database.db",
                  "colmap/sparse/0/*", "colmap/sparse/0/", "colmap/sparse/", "colmap/")


@dataclass(frozen=True)
class InputImages:
    """The checked input images.

    Attributes:
        source: the user's folder.
        folder: where SfM reads them: ``source``, or copies made for COLMAP (colmap_copies) when some image
            carries an EXIF rotation, is in a format COLMAP cannot decode (WebP) or has a non-UTF-8 name.
        names: the names in ``folder`` (those the scene's images/ get), in the order of the sorted originals.
        originals: the user's file names, printable (undecodable bytes as %XX), in the same order.
        height, width: the common image size (after EXIF orientation).
    """

    source: Path
    folder: Path
    names: tuple[str, ...]
    height: int
    width: int
    originals: tuple[str, ...] = ()

    def original(self, name: str) -> str:
        """The user's file name of the COLMAP name ``name``."""
        return dict(zip(self.names, self.originals or self.names)).get(name, name)


@dataclass(frozen=True)
class ModelArrays:
    """A finished (undistorted) model as plain arrays; N registered images sorted by name, P points.

    Attributes:
        names, image_ids: [N] image names and COLMAP image ids.
        K: [N, 3, 3] pinhole intrinsics; w2c: [N, 3, 4] world-to-camera (OpenCV axes).
        height, width: image size of every camera.
        xyz: [P, 3] points; rgb: [P, 3] uint8 colours.
        seen: N index arrays [k_i] into the points, the points each image observes.
    """

    names: tuple[str, ...]
    image_ids: tuple[int, ...]
    K: np.ndarray  # [N, 3, 3]
    w2c: np.ndarray  # [N, 3, 4]
    height: int
    width: int
    xyz: np.ndarray  # [P, 3]
    rgb: np.ndarray  # [P, 3]
    seen: list[np.ndarray]


@dataclass(frozen=True)
class WrittenScene:
    names: tuple[str, ...]
    cameras: Cameras
    near: torch.Tensor  # [N]
    far: torch.Tensor  # [N]
    num_points: int


def check_output(images_dir: Path, out_dir: Path, overwrite: bool) -> None:
    """Refuse an output folder that is, holds or lies inside the input images, cannot be written, or holds
    files already (without ``overwrite``)."""
    check_output_path(out_dir, [images_dir], kind="input images")
    if holds_files(out_dir) and not overwrite:
        raise UserError(f"{out_dir} already exists; pass --overwrite to replace the scene files insertnerf wrote "
                        "there (other files are kept), or choose another --out.")


@contextmanager
def staging_folder(out_dir: Path) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``out_dir``; on success its files go to ``out_dir``, and the
    temporary folder is removed either way."""
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(out_dir)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}{_PARTIAL}{os.getpid()}-", dir=out_dir.parent))
    try:
        yield tmp
        record_tree(tmp, OWNER)
        _move_into_place(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def remove_stale_staging(out_dir: Path) -> None:
    """Remove temporary folders of ``out_dir`` left by runs that were killed (their process is gone)."""
    for leftover in out_dir.parent.glob(f".{out_dir.name}{_PARTIAL}*"):
        pid = leftover.name[len(f".{out_dir.name}{_PARTIAL}"):].split("-")[0]
        if pid.isdigit() and not process_alive(int(pid)):
            shutil.rmtree(leftover, ignore_errors=True)


def _move_into_place(tmp: Path, out_dir: Path) -> None:
    """Make ``tmp`` the output: the files insertnerf wrote in ``out_dir`` before (recorded, or the legacy
    names) are replaced by the new ones; other files stay."""
    if out_dir.exists():
        OutputRecord(out_dir, OWNER).remove(legacy=LEGACY_OUTPUTS)
    move_into(tmp, out_dir, OWNER)


def read_inputs(images_dir: Path, copy_dir: Path) -> InputImages:
    """Find and decode every image; refuse too few, unreadable or mixed-size sets.

    When an image has an EXIF rotation (COLMAP ignores the tag), is WebP (COLMAP cannot decode it) or has a name
    that is not UTF-8 (pycolmap takes text), every image is copied to ``copy_dir`` as COLMAP can read it, so that
    the poses, the undistorted images and every later reader see the same pixels.
    """
    paths = find_images(images_dir)
    if len(paths) < MIN_IMAGES:
        raise UserError(f"found {len(paths)} image(s) in {images_dir} (extensions {', '.join(IMAGE_EXTENSIONS)}); "
                        f"need at least {MIN_IMAGES} overlapping photos of one scene.")
    sizes: dict[tuple[int, int], list[str]] = {}
    unreadable, rotated = [], []
    for path in paths:
        try:
            h, w = read_rgb(path).shape[:2]
        except SceneError:
            unreadable.append(printable_name(path.name))
            continue
        sizes.setdefault((h, w), []).append(printable_name(path.name))
        if exif_orientation(path) != 1:
            rotated.append(path)
    if unreadable:
        raise UserError(f"cannot read {len(unreadable)} file(s) in {images_dir}: {', '.join(unreadable[:10])}"
                        f"{' ...' if len(unreadable) > 10 else ''}; remove or re-export them.")
    if len(sizes) > 1:
        listed = "; ".join(f"{w}x{h}: {len(n)} (e.g. {n[0]})" for (h, w), n in sizes.items())
        raise UserError(f"the images in {images_dir} have {len(sizes)} different sizes ({listed}); one camera "
                        "is assumed, so resize them to one size first.")
    (height, width), = sizes
    originals = tuple(printable_name(p.name) for p in paths)
    folder, names = colmap_readable(paths, set(rotated), images_dir, copy_dir)
    return InputImages(images_dir, folder, names, height, width, originals)


def printable_name(name: str) -> str:
    """A file name as UTF-8 text: bytes that are not UTF-8 (os.fsdecode's surrogates) become %XX."""
    return "".join(f"%{ord(c) - 0xDC00:02X}" if 0xDC80 <= ord(c) <= 0xDCFF else c for c in name)


def _needs_copy(path: Path) -> bool:
    """COLMAP cannot take this file as it is: a format its decoder lacks, or a name that is not UTF-8 text."""
    return path.suffix.lower() in COLMAP_UNDECODABLE or printable_name(path.name) != path.name


def colmap_readable(paths: list[Path], rotated: set[Path], base: Path, copies: Path) -> tuple[Path, tuple[str, ...]]:
    """(the folder COLMAP reads, each image's name in it, in the order of ``paths``): the files themselves, named
    relative to ``base``, when COLMAP reads them as our loader does; else copies in ``copies`` (colmap_copies) for
    all of them, ``rotated`` (an EXIF rotation COLMAP would ignore) among them."""
    if not rotated and not any(_needs_copy(p) for p in paths):
        return base, tuple(p.relative_to(base).as_posix() for p in paths)
    return copies, colmap_copies(paths, rotated, copies)


def colmap_copies(paths: list[Path], rotated: set[Path], folder: Path) -> tuple[str, ...]:
    """Copy every image into ``folder`` (inside the temporary output, never the input) for COLMAP: the bytes as
    they are when COLMAP can read them, else decoded and written as PNG (lossless) with the EXIF rotation applied;
    names made UTF-8 (%XX) and .png for converted files. Returns the new names, in the order of ``paths``."""
    folder.mkdir(parents=True, exist_ok=True)
    names: list[str] = []
    for path in paths:
        convert = path in rotated or path.suffix.lower() in COLMAP_UNDECODABLE
        name = printable_name(path.name)
        if path.suffix.lower() in COLMAP_UNDECODABLE:
            name = f"{Path(name).stem}.png"
        stem, suffix, n = Path(name).stem, Path(name).suffix, 1
        while name in names:
            name, n = f"{stem}-{n}{suffix}", n + 1
        names.append(name)
        if not convert:
            shutil.copyfile(path, folder / name)
            continue
        rgb = (read_rgb(path) * 255.0 + 0.5).astype(np.uint8)
        if not cv2.imwrite(str(folder / name), rgb[..., ::-1]):
            raise UserError(f"cannot write a copy of {printable_name(path.name)} for COLMAP to {folder}; check "
                            "free disk space.")
    return tuple(names)


def _depth_bounds(model: ModelArrays) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-image near/far [N]: percentiles of the depths of the points each image sees."""
    all_near, all_far = [], []
    for w2c, seen in zip(model.w2c, model.seen):
        depth = (model.xyz[seen] @ w2c[:, :3].T + w2c[:, 3])[:, 2]  # [k]
        depth = depth[depth > 0]
        lo, hi = np.percentile(depth, DEPTH_PERCENTILES) if depth.size else (np.nan, np.nan)
        all_near.append(lo)
        all_far.append(hi)
    near, far = np.array(all_near), np.array(all_far)
    # A registered image always sees points; the fallback only guards against a degenerate model.
    near = np.where(np.isfinite(near), near, np.nanmin(near) if np.isfinite(near).any() else 0.1)
    far = np.where(np.isfinite(far), far, np.nanmax(far) if np.isfinite(far).any() else 100.0)
    return torch.from_numpy(near), torch.from_numpy(far)


def write_scene(root: Path, model: ModelArrays) -> WrittenScene:
    """transforms.json, sparse.ply and cameras.ply for the undistorted model (its images are in root/images)."""
    n = len(model.names)
    w2c = np.zeros((n, 4, 4))
    w2c[:, :3], w2c[:, 3, 3] = model.w2c, 1.0
    cameras = Cameras.from_w2c(torch.from_numpy(model.K.astype(np.float64)), torch.from_numpy(w2c),
                               model.height, model.width)
    near, far = _depth_bounds(model)
    write_nerfstudio_transforms(root / "transforms.json", cameras, [f"images/{name}" for name in model.names],
                                near=near, far=far,
                                extra={"ply_file_path": "sparse.ply", "colmap_model": "colmap/sparse/0"},
                                frame_extras=[{"colmap_im_id": i} for i in model.image_ids])
    write_point_cloud(root / "sparse.ply", model.xyz, model.rgb)
    write_camera_frustums(root / "cameras.ply", cameras)
    return WrittenScene(model.names, cameras, near, far, len(model.xyz))
