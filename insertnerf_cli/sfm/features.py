"""SIFT keypoints of a posed scene's photos, for triangulate: COLMAP's SIFT on each photo shrunk to a fixed size
(poses/extraction.py: in a child process, so Ctrl-C stops it at once), read back from its database.

OpenCV's SIFT found as many keypoints in a third of the time, but its points cost room 0.7 dB at 3 views against
COLMAP's own (docs/research-log.md, Poses and triangulation), so extraction stays COLMAP's.
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import pycolmap

from insertnerf_cli.poses.extraction import extract_sift
from insertnerf_cli.poses.folder import colmap_readable
from insertnerf_cli.poses.stages import pycolmap_log
from insertnerf_cli.scenes.images import exif_orientation

# SIFT on photos no larger than this: the points guide samples to within a few per cent of depth, which 768 px
# keypoints locate well enough; extraction and matching cost about half of 1024 px's. Smaller photos lost points,
# and with them 0.2-0.5 dB at 3 views (measured: docs/research-log.md, Poses and triangulation).
MAX_IMAGE_SIZE = 768
# SIFT's contrast threshold, well below COLMAP's 1/150: the keypoints on faint texture (tissue, a plain wooden box,
# a lab's far wall) that matching along the epipolar lines can place; at 768 px it also makes up the keypoints the
# smaller photos lose (measured: docs/research-log.md, Poses and triangulation).
PEAK_THRESHOLD = 0.001
# At most this many keypoints per photo, the strongest.
MAX_FEATURES = 8192


@dataclass(frozen=True)
class FeatureOptions:
    """How photos are described: their long side for SIFT, its contrast threshold, keypoints kept per photo, CPU
    threads (-1: all)."""

    max_image_size: int = MAX_IMAGE_SIZE
    peak_threshold: float = PEAK_THRESHOLD
    max_features: int = MAX_FEATURES
    num_threads: int = -1


@dataclass(frozen=True)
class PhotoFeatures:
    """One photo's keypoints.

    xy: [N, 2] float64 pixel positions in the full-size photo, COLMAP's convention (the first pixel's centre at
        0.5, 0.5), the convention of the scene's intrinsics.
    descriptors: [N, 128] uint8 SIFT descriptors (COLMAP's RootSIFT, scaled to 512).
    """

    xy: np.ndarray
    descriptors: np.ndarray


def photo_features(paths: Sequence[Path], root: Path, options: FeatureOptions = FeatureOptions()) -> list[PhotoFeatures]:
    """PhotoFeatures of each photo at ``paths`` (under the scene folder ``root``), in that order, as the scene
    loader reads them (WebP decoded, EXIF rotation applied: poses/folder.colmap_readable)."""
    with tempfile.TemporaryDirectory(prefix="insertnerf-features-") as tmp, pycolmap_log(False):
        work = Path(tmp)
        folder, names = colmap_readable(list(paths), {p for p in paths if exif_orientation(p) != 1}, root,
                                        work / "images")
        names = list(names)
        database = work / "database.db"
        extraction = pycolmap.FeatureExtractionOptions(max_image_size=options.max_image_size,
                                                       num_threads=options.num_threads)
        extraction.sift.peak_threshold = options.peak_threshold
        extraction.sift.max_num_features = options.max_features
        missing, _ = extract_sift(database, folder, names, pycolmap.CameraMode.PER_IMAGE, extraction)
        if missing:
            raise RuntimeError(f"COLMAP read no features from {len(missing)} images (first: {missing[0]})")
        with pycolmap.Database.open(database) as db:
            ids = {image.name: image.image_id for image in db.read_all_images()}
            return [PhotoFeatures(np.asarray(db.read_keypoints(ids[name])[:, :2], dtype=np.float64),
                                  np.asarray(db.read_descriptors(ids[name]).data)) for name in names]
