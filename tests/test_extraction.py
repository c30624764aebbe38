"""COLMAP's SIFT extraction as poses and triangulate share it (poses/extraction.py)."""
from __future__ import annotations

import cv2
import numpy as np
import pycolmap

from insertnerf_cli.poses.extraction import extract_sift


def _textured(path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    image = cv2.resize(rng.integers(0, 256, (24, 32, 3), dtype=np.uint8), (128, 96), interpolation=cv2.INTER_NEAREST)
    assert cv2.imwrite(str(path), image)


def test_extract_sift_writes_keypoints_and_names_the_images_colmap_could_not_read(tmp_path):
    folder = tmp_path / "images"
    folder.mkdir()
    _textured(folder / "a.png", 0)
    _textured(folder / "b.png", 1)
    (folder / "broken.png").write_bytes(b"not an image")
    database = tmp_path / "work" / "database.db"
    extraction = pycolmap.FeatureExtractionOptions(max_image_size=128, num_threads=1)

    unread, keypoints = extract_sift(database, folder, ["a.png", "broken.png", "b.png"],
                                     pycolmap.CameraMode.PER_IMAGE, extraction)

    assert unread == ["broken.png"]
    with pycolmap.Database.open(database) as db:
        counts = {image.name: len(db.read_keypoints(image.image_id)) for image in db.read_all_images()}
    assert set(counts) == {"a.png", "b.png"} and min(counts.values()) > 0
    assert keypoints == sum(counts.values())
