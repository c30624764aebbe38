"""COLMAP's SIFT extraction into a database, in a child process (poses/child.py: Ctrl-C stops it at once), for
both `poses` (one camera for all photos) and the triangulation at known poses (sfm/features.py: one per photo)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import pycolmap

from insertnerf_cli.poses.child import run_in_child


def extract_sift(database: Path, folder: Path, names: Sequence[str], camera_mode: "pycolmap.CameraMode",
                 extraction: "pycolmap.FeatureExtractionOptions",
                 reader: "pycolmap.ImageReaderOptions | None" = None) -> tuple[list[str], int]:
    """SIFT keypoints of the images ``names`` under ``folder``, written into ``database``.

    Returns:
        (the names COLMAP read no image for, in ``names``' order: its decoder skips those silently; the number of
        keypoints in the database).
    """
    database.parent.mkdir(parents=True, exist_ok=True)
    options = {} if reader is None else {"reader_options": reader}
    run_in_child(lambda send: pycolmap.extract_features(database, folder, image_names=list(names),
                                                        camera_mode=camera_mode, extraction_options=extraction,
                                                        device=pycolmap.Device.cpu, **options))
    with pycolmap.Database.open(database) as db:
        read = {image.name for image in db.read_all_images()}
        keypoints = db.num_keypoints()
    return [name for name in names if name not in read], keypoints
