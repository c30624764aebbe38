"""What `render` renders from: a scene folder, a plain folder of photos, or a COLMAP project whose images/ holds
photos with no poses yet (both posed with pycolmap once into OUT/poses/ and reused), and the weights (fine-tuned
with --finetune). No click here."""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import torch

from insertnerf_cli.errors import UserError
from insertnerf_cli.exporters.outputs import OWNER as RENDER_OWNER, POINTS_DIR, POSES_DIR
from insertnerf_cli.files.outdir import OutputRecord, record_name, remove_if_empty
from insertnerf_cli.finetune import FinetuneConfig, cached_finetune
from insertnerf_cli.finetune.render_cache import RECORD, WEIGHTS
from insertnerf_cli.poses.estimate import PosesOptions, estimate_poses
from insertnerf_cli.scenes import detect_format, find_images, load_scene
from insertnerf_cli.scenes.points import ScenePoints
from insertnerf_cli.sfm.points_cache import check_cache_folder

# COLMAP's own project layout keeps the photos here (beside database.db and sparse/ once it has run).
PROJECT_IMAGES = "images"


@dataclass(frozen=True)
class Photos:
    """A folder of photos without poses: ``folder`` holds them; ``fingerprint`` lists [name, size, mtime_ns]."""

    folder: Path
    fingerprint: list[list]


def _image_fingerprint(folder: Path) -> list[list] | None:
    """Names, sizes and modification times of the images directly in ``folder`` (None for none)."""
    try:
        images = find_images(folder)
    except UserError:
        return None
    return [[p.name, p.stat().st_size, p.stat().st_mtime_ns] for p in images] or None


def points_cache(given: Path | None, scene_dir: Path, out_dir: Path | None,
                 owner: str) -> tuple[Path | None, Callable[[Path], None] | None]:
    """(folder, claim) for triangulate.with_points: where a run keeps the SfM points it triangulates at a scene's
    poses (sfm/points_cache.py), and how a file written there joins the run's output record.

    ``given`` (--points-cache) is a folder the user keeps between runs into other output folders: its files are
    not recorded, so `--overwrite` never removes them; it is checked here, before any long work, to lie outside
    the scene. Else OUT/points/ (``out_dir``), recorded as ``owner``'s; else nowhere.
    """
    if given is not None:
        check_cache_folder(given, scene_dir)
        return given, None
    if out_dir is None:
        return None, None
    return out_dir / POINTS_DIR, lambda file: OutputRecord(out_dir, owner).claim(POINTS_DIR,
                                                                                 record_name(out_dir, file))


def unposed_photos(scene_dir: Path) -> Photos | None:
    """The photos to pose when ``scene_dir`` is no scene: its own images, else those of its images/ sub-folder
    (a COLMAP project before COLMAP ran); None when it is a scene (or neither, for load_scene to explain)."""
    if detect_format(scene_dir) is not None:
        return None
    for folder in (scene_dir, scene_dir / PROJECT_IMAGES):
        fingerprint = _image_fingerprint(folder) if folder.is_dir() else None
        if fingerprint:
            return Photos(folder, fingerprint)
    return None


def posed_photos(photos: Photos, out_dir: Path, created: bool):
    """The scene pycolmap makes of a folder of photos, estimated once into OUT/poses and reused after.

    A failure leaves no trace in an OUT this run ``created`` (no record, no folder)."""
    poses_dir = out_dir / POSES_DIR
    if not (poses_dir / "transforms.json").is_file():
        print(f"{photos.folder} is a folder of photos without poses: estimating them with COLMAP into {poses_dir} "
              "(once; later runs reuse them)", file=sys.stderr)
        OutputRecord(out_dir, RENDER_OWNER).claim(POSES_DIR)
        try:
            estimate_poses(photos.folder, poses_dir, PosesOptions(overwrite=True))
        except BaseException:
            if created:
                OutputRecord(out_dir, RENDER_OWNER).remove()
                remove_if_empty(out_dir)
            raise
    return load_scene(poses_dir)


def finetuned(scene_dir: Path, out_dir: Path, checkpoint: Path, minutes: float, views: int,
              resolution: int | None, device: str, sfm_depth: bool = True,
              points: ScenePoints | None = None) -> Path:
    """The weights `render --finetune M` renders with: fine-tuned for M minutes at the render's resolution and
    number of reference views, kept in OUT and reused by a later run with the same inputs. ``points``: the
    render's SfM points of the normalised scene, so the fine-tune need not
    triangulate again (None: it does when it must)."""
    OutputRecord(out_dir, RENDER_OWNER).claim(WEIGHTS, RECORD)
    ft = FinetuneConfig(minutes=minutes, views=views, resolution=resolution, sfm_depth=sfm_depth)
    return cached_finetune(scene_dir, out_dir, checkpoint, ft, torch.device(device), points)
