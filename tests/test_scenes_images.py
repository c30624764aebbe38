"""Image reading: extensions, EXIF orientation, grayscale, alpha, 16 bits, unreadable files, resizing."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image, ImageOps

from insertnerf_cli.scenes import Distortion, SceneError, find_images, read_rgb, resize
from insertnerf_cli.scenes.images import image_size, undistort


def asymmetric_rgb(height: int = 5, width: int = 7) -> np.ndarray:
    """uint8 [H, W, 3] with every pixel different, so any flip or turn changes it."""
    values = np.arange(height * width * 3, dtype=np.int64).reshape(height, width, 3)
    return (values * 7 % 251).astype(np.uint8)


def test_find_images_sorted_case_insensitive(tmp_path: Path) -> None:
    for name in ("b.JPG", "a.png", "c.Jpeg", "d.tif", "e.BMP", "f.webp", "notes.txt", ".hidden.png"):
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / "sub.png").mkdir()
    assert [p.name for p in find_images(tmp_path)] == ["a.png", "b.JPG", "c.Jpeg", "d.tif", "e.BMP", "f.webp"]


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_matches_pillow(tmp_path: Path, orientation: int) -> None:
    path = tmp_path / "o.jpg"
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(asymmetric_rgb(6, 10)).save(path, exif=exif, quality=100, subsampling=0)
    with Image.open(path) as im:
        expected = np.asarray(ImageOps.exif_transpose(im).convert("RGB"), dtype=np.float32) / 255
    got = read_rgb(path)
    assert got.shape == expected.shape
    np.testing.assert_allclose(got, expected, atol=1e-6)  # same decoded JPEG, only the turn differs
    assert image_size(path) == got.shape[:2]


def test_grayscale_is_promoted(tmp_path: Path) -> None:
    gray = np.arange(20, dtype=np.uint8).reshape(4, 5) * 10
    cv2.imwrite(str(tmp_path / "g.png"), gray)
    img = read_rgb(tmp_path / "g.png")
    assert img.shape == (4, 5, 3) and img.dtype == np.float32
    np.testing.assert_allclose(img, np.repeat(gray[..., None], 3, 2) / 255.0, atol=1e-7)


def test_rgba_is_composited_on_the_background(tmp_path: Path) -> None:
    rgba = np.zeros((2, 2, 4), np.uint8)
    rgba[..., 0] = 255  # red, opacity 0, 1/3, 2/3, 1
    rgba[..., 3] = np.array([[0, 85], [170, 255]])
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    img = read_rgb(tmp_path / "a.png", background=(0.0, 0.0, 1.0))
    alpha = rgba[..., 3] / 255.0
    np.testing.assert_allclose(img[..., 0], alpha, atol=1e-6)
    np.testing.assert_allclose(img[..., 2], 1 - alpha, atol=1e-6)
    np.testing.assert_allclose(read_rgb(tmp_path / "a.png")[0, 0], [1, 1, 1])  # white by default


def test_sixteen_bit_keeps_precision(tmp_path: Path) -> None:
    img16 = np.zeros((3, 4, 3), np.uint16)
    img16[..., 1] = np.arange(12).reshape(3, 4) + 1000  # steps far below one 8-bit level
    cv2.imwrite(str(tmp_path / "d.png"), img16)
    img = read_rgb(tmp_path / "d.png")
    np.testing.assert_allclose(img[..., 1], (np.arange(12).reshape(3, 4) + 1000) / 65535.0, rtol=1e-6)


def test_unreadable_file_is_named(tmp_path: Path) -> None:
    (tmp_path / "broken.png").write_bytes(b"not a png")
    with pytest.raises(SceneError, match="broken.png"):
        read_rgb(tmp_path / "broken.png")
    with pytest.raises(SceneError, match="missing.png"):
        read_rgb(tmp_path / "missing.png")


def test_resize_shrinks_by_area_and_keeps_constant_images() -> None:
    checker = np.indices((8, 8)).sum(0) % 2  # [8, 8] one-pixel checkerboard
    img = np.repeat(checker[..., None].astype(np.float32), 3, 2)
    small = resize(img, 4, 4)
    np.testing.assert_allclose(small, 0.5, atol=1e-6)  # area averaging: no aliasing
    big = resize(np.full((3, 5, 3), 0.25, np.float32), 7, 9)
    assert big.shape == (7, 9, 3)
    np.testing.assert_allclose(big, 0.25, atol=1e-6)


def test_undistort_moves_a_dot_to_its_pinhole_place() -> None:
    K = np.array([[40.0, 0, 32.0], [0, 40.0, 24.0], [0, 0, 1]])
    coeffs = (-0.4, 0.05, 0.001, -0.002)  # moves the dot by about 5 pixels
    point = np.array([[[0.6, -0.4, 1.0]]])  # camera frame
    distorted = cv2.projectPoints(point, np.zeros(3), np.zeros(3), K, np.array(coeffs))[0]
    img = np.zeros((48, 64, 3), np.float32)
    col, row = (distorted[0, 0] + 0.5).astype(int)  # OpenCV pixel centres at integers -> our +0.5
    img[row - 1:row + 2, col - 1:col + 2] = 1.0
    out = undistort(img, K + np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]]), Distortion("opencv", coeffs))
    rows, cols = np.nonzero(out[..., 0] > 0.5)
    pinhole = K[:2, :2] @ point[0, 0, :2] + K[:2, 2]  # where the pinhole camera sees it (integer-centre pixels)
    assert abs(cols.mean() - pinhole[0]) < 1.0 and abs(rows.mean() - pinhole[1]) < 1.0
