"""Image files: finding them, reading them as float RGB in [0, 1], resizing them.

Pixels are decoded by OpenCV (8/16-bit, float TIFF, alpha, grayscale) and the EXIF orientation tag is read
with Pillow and applied here, so the same photo reads the same way whatever the decoder's own habits.
"""
from __future__ import annotations

import io
import os
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from insertnerf_cli.errors import SceneError, os_error_message

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")

_EXIF_ORIENTATION = 0x0112
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MAX_PIXELS = 1 << 28  # 268 megapixels: past any photo this tool renders from; more is a damaged header


@dataclass(frozen=True)
class Distortion:
    """Lens distortion of one view, removed when its image is loaded.

    Attributes:
        model: "opencv" (cv2.undistort order k1, k2, p1, p2[, k3[, k4, k5, k6]]) or "fisheye" (k1..k4).
        coeffs: the coefficients; they act on normalised image coordinates, so they hold at any image size.
        zoom: the undistorted pinhole camera's focal lengths over the photo's (principal point and size kept):
            above 1 where the undistorted image would otherwise have corners with no source pixel
            (see :func:`blank_free_zoom`), which would read as black surfaces in a reference view.
    """

    model: Literal["opencv", "fisheye"]
    coeffs: tuple[float, ...]
    zoom: float = 1.0


def is_image(path: Path) -> bool:
    """True for a regular file whose extension (any case) is an image extension we read."""
    return path.suffix.lower() in IMAGE_EXTENSIONS and path.is_file() and not path.name.startswith(".")


def find_images(folder: str | os.PathLike) -> list[Path]:
    """Image files directly inside ``folder``, sorted by name (hidden files skipped)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SceneError(f"{folder} is not a folder")
    return sorted((p for p in folder.iterdir() if is_image(p)), key=lambda p: p.name)


def _decode(path: Path) -> np.ndarray:
    """Raw pixels [H, W] or [H, W, C] (BGR/BGRA order) as stored, any depth."""
    try:
        data = np.fromfile(path, dtype=np.uint8)  # fromfile + imdecode copes with any path encoding
    except OSError as err:
        raise SceneError(os_error_message(err)) from None
    _check_declared_size(data, path)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise SceneError(f"cannot decode image {path}: not a readable image file (corrupt or unsupported)")
    return img


def _check_declared_size(data: np.ndarray, path: Path) -> None:
    """Refuse a header that declares more than MAX_PIXELS pixels before the decoder allocates them (one flipped bit
    in a PNG's IHDR made OpenCV allocate 1 GB for a 24x32 image)."""
    from PIL import Image

    if data[:8].tobytes() == _PNG_SIGNATURE:
        _check_png_chunks(data.tobytes(), path)
    try:
        with Image.open(io.BytesIO(data.tobytes())) as im:  # reads the header only
            width, height = im.size
    except Image.DecompressionBombError:  # Pillow's own limit (about 179 megapixels) was passed
        width, height = MAX_PIXELS, 1
    except Exception:  # noqa: BLE001 - a header Pillow cannot parse is left to OpenCV's decoder
        return
    if width * height >= MAX_PIXELS:
        raise SceneError(f"cannot decode image {path}: its header declares {width * height / 1e6:.0f}+ megapixels, "
                         f"over {MAX_PIXELS / 1e6:.0f} (damaged, or too large to render from)")


def _check_png_chunks(data: bytes, path: Path) -> None:
    """Walk a PNG's chunks: the header's checksum must hold and every declared length must fit in the file.
    OpenCV allocated 1 GB for a 32x24 PNG with a flipped IHDR byte, and again for one whose IDAT length was
    flipped, before finding the file damaged."""
    at = 8
    while at + 12 <= len(data):
        length, kind = int.from_bytes(data[at:at + 4], "big"), data[at + 4:at + 8]
        end = at + 12 + length
        if end > len(data):
            break
        if kind == b"IHDR" and zlib.crc32(data[at + 4:end - 4]) != int.from_bytes(data[end - 4:end], "big"):
            break
        if kind == b"IEND":
            return
        at = end
    raise SceneError(f"cannot decode image {path}: damaged PNG (a chunk at byte {at} is cut short or fails its "
                     "checksum); re-export it")


def exif_orientation(path: Path) -> int:
    """The EXIF orientation tag (1..8) of an image file, 1 when absent or unreadable."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            value = int(im.getexif().get(_EXIF_ORIENTATION, 1))
    except Exception:  # noqa: BLE001 - a file Pillow cannot parse simply has no orientation we can honour
        return 1
    return value if 1 <= value <= 8 else 1


def apply_orientation(img: np.ndarray, orientation: int) -> np.ndarray:
    """Turn stored pixels [H, W, ...] into the upright image that an EXIF ``orientation`` (1..8) describes."""
    if orientation in (5, 6, 7, 8):
        img = np.swapaxes(img, 0, 1)  # every odd-quarter turn is a transpose followed by a flip
    flips = {2: (False, True), 3: (True, True), 4: (True, False),
             5: (False, False), 6: (False, True), 7: (True, True), 8: (True, False)}
    flip_rows, flip_cols = flips.get(orientation, (False, False))
    if flip_rows:
        img = img[::-1]
    if flip_cols:
        img = img[:, ::-1]
    return np.ascontiguousarray(img)


def _to_unit_float(img: np.ndarray, path: Path) -> np.ndarray:
    """Integer or float pixels -> float32 in [0, 1], using the full range of the integer type."""
    if np.issubdtype(img.dtype, np.integer):
        return img.astype(np.float32) / float(np.iinfo(img.dtype).max)
    if np.issubdtype(img.dtype, np.floating):
        return np.clip(np.nan_to_num(img.astype(np.float32)), 0.0, 1.0)
    raise SceneError(f"cannot read image {path}: unsupported pixel type {img.dtype}")


def read_rgb(path: str | os.PathLike, background: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> np.ndarray:
    """Read an image as upright float32 RGB [H, W, 3] in [0, 1].

    EXIF orientation is honoured, grayscale is promoted to RGB, 16-bit images keep their precision, and an
    alpha channel is composited onto ``background`` (RGB in [0, 1]). Unreadable files raise SceneError.
    """
    path = Path(path)
    raw = _decode(path)
    img = _to_unit_float(raw, path)
    if img.ndim == 2:
        img = img[..., None]
    channels = img.shape[2]
    if channels in (1, 2):  # gray or gray + alpha
        color, alpha = np.repeat(img[..., :1], 3, axis=2), img[..., 1:2] if channels == 2 else None
    elif channels in (3, 4):
        color, alpha = img[..., 2::-1], img[..., 3:4] if channels == 4 else None  # BGR(A) -> RGB
    else:
        raise SceneError(f"cannot read image {path}: {channels} channels (expected 1 to 4)")
    if alpha is not None:
        bg = np.asarray(background, dtype=np.float32).reshape(1, 1, 3)
        color = color * alpha + bg * (1.0 - alpha)
    return apply_orientation(color.astype(np.float32), exif_orientation(path))


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """(height, width) of an image after EXIF orientation, without decoding the pixels when Pillow can."""
    from PIL import Image

    path = Path(path)
    try:
        with Image.open(path) as im:
            w, h = im.size
            orientation = int(im.getexif().get(_EXIF_ORIENTATION, 1))
    except Exception:  # noqa: BLE001 - let the full decoder give the precise error or the size
        h, w = read_rgb(path).shape[:2]
        return h, w
    return (w, h) if orientation in (5, 6, 7, 8) else (h, w)


def resize(img: np.ndarray, height: int, width: int) -> np.ndarray:
    """Resize [H, W, C] to [height, width, C]: area averaging when shrinking (no aliasing), bilinear otherwise."""
    if img.shape[:2] == (height, width):
        return img
    shrinking = height * width < img.shape[0] * img.shape[1]
    out = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    return out.reshape(height, width, *img.shape[2:])


def _opencv_K(K: np.ndarray) -> np.ndarray:
    """Our K [3, 3] (pixel centres at +0.5, as COLMAP) as OpenCV's (centres at integers)."""
    K = np.array(K, dtype=np.float64)
    K[:2, 2] -= 0.5
    return K


def _photo_K(K: np.ndarray, zoom: float) -> np.ndarray:
    """The photo's camera matrix from the undistorted camera's K [3, 3] (focal lengths divided by ``zoom``)."""
    K = np.array(K, dtype=np.float64)
    K[:2, :2] /= zoom
    return K


def undistort(img: np.ndarray, K: np.ndarray, distortion: Distortion) -> np.ndarray:
    """Remove lens distortion from [H, W, C]; K [3, 3] is the undistorted camera at this size (the photo's focal
    lengths times ``distortion.zoom``). Pixels whose source falls outside the photo come out black."""
    coeffs = np.asarray(distortion.coeffs, dtype=np.float64)
    K_out, K_photo = _opencv_K(K), _opencv_K(_photo_K(K, distortion.zoom))
    if distortion.model == "fisheye":
        return cv2.fisheye.undistortImage(img, K_photo, coeffs[:4], Knew=K_out).reshape(img.shape)
    return cv2.undistort(img, K_photo, coeffs, newCameraMatrix=K_out).reshape(img.shape)


_BORDER_SAMPLES = 64  # per side: dense enough that a bulge between two samples stays under a tenth of a pixel
MAX_ZOOM = 4.0  # a lens needing more is a fisheye past what a pinhole image can hold; leave its corners blank


def _border_pixels(height: int, width: int) -> np.ndarray:
    """[4 * _BORDER_SAMPLES, 2] centres of the outermost pixels (our convention, +0.5), corners included."""
    xs = np.linspace(0.5, width - 0.5, _BORDER_SAMPLES)
    ys = np.linspace(0.5, height - 0.5, _BORDER_SAMPLES)
    return np.concatenate([np.stack([xs, np.full_like(xs, 0.5)], 1), np.stack([xs, np.full_like(xs, height - 0.5)], 1),
                           np.stack([np.full_like(ys, 0.5), ys], 1), np.stack([np.full_like(ys, width - 0.5), ys], 1)])


def _sources(K_photo: np.ndarray, pixels: np.ndarray, distortion: Distortion, zoom: float) -> np.ndarray:
    """Where in the photo (OpenCV pixel coordinates) pixels [P, 2] (ours, +0.5) of the undistorted image take their
    colour from, [P, 2]; the photo's camera is K_photo [3, 3], the undistorted one the same with its focal lengths
    times ``zoom``."""
    normalised = (pixels - K_photo[:2, 2]) / (zoom * np.diag(K_photo)[:2])  # [P, 2] on the z = 1 plane
    coeffs = np.asarray(distortion.coeffs, dtype=np.float64)
    if distortion.model == "fisheye":
        return cv2.fisheye.distortPoints(normalised[None], _opencv_K(K_photo), coeffs[:4])[0]
    points = np.concatenate([normalised, np.ones((len(normalised), 1))], 1)[:, None]  # [P, 1, 3]
    return cv2.projectPoints(points, np.zeros(3), np.zeros(3), _opencv_K(K_photo), coeffs)[0][:, 0]


def _inside(source: np.ndarray, height: int, width: int) -> np.ndarray:
    """[P] True where source pixels [P, 2] (OpenCV coordinates) lie in a height x width photo."""
    tolerance = 1e-3  # pixels: an edge sample that lands on the photo's last pixel centre is inside
    return np.isfinite(source).all(-1) & (source >= -tolerance).all(-1) \
        & (source[:, 0] <= width - 1 + tolerance) & (source[:, 1] <= height - 1 + tolerance)


def _sources_inside(K_photo: np.ndarray, height: int, width: int, distortion: Distortion, zoom: float) -> bool:
    """True when every border pixel of the undistorted image (the photo's camera K_photo [3, 3] zoomed by ``zoom``)
    has its source inside the photo; the distortion models we read are monotonic in the radius there, so the
    inside follows."""
    return bool(_inside(_sources(K_photo, _border_pixels(height, width), distortion, zoom), height, width).all())


def source_share(K_photo: np.ndarray, height: int, width: int, distortion: Distortion) -> float:
    """The share of the undistorted image (the photo's camera K_photo [3, 3] zoomed by ``distortion.zoom``) that has
    a source pixel in the photo, on a 24 x 24 grid of pixel centres."""
    ys, xs = np.meshgrid(np.linspace(0.5, height - 0.5, 24), np.linspace(0.5, width - 0.5, 24), indexing="ij")
    grid = np.stack([xs.ravel(), ys.ravel()], 1)
    return float(_inside(_sources(np.asarray(K_photo, dtype=np.float64), grid, distortion, distortion.zoom),
                         height, width).mean())


def blank_free_zoom(K: np.ndarray, height: int, width: int, distortion: Distortion) -> float:
    """The smallest zoom >= 1 (undistorted focal / photo focal) at which the undistorted height x width image has
    a source pixel everywhere, as COLMAP's undistorter crops to; K [3, 3] is the photo's camera (zoom 1).

    Barrel distortion needs none (1.0); pincushion (COLMAP's SIMPLE_RADIAL with k > 0) a few percent. Capped at
    MAX_ZOOM, past which the corners stay black.
    """
    K = np.asarray(K, dtype=np.float64)
    if _sources_inside(K, height, width, distortion, 1.0):
        return 1.0
    low, high = 1.0, 2.0
    while not _sources_inside(K, height, width, distortion, high):
        low, high = high, 2.0 * high
        if high > MAX_ZOOM:
            return MAX_ZOOM
    for _ in range(30):  # bisection to ~1e-9 of the zoom: far below a pixel
        middle = 0.5 * (low + high)
        inside = _sources_inside(K, height, width, distortion, middle)
        low, high = (low, middle) if inside else (middle, high)
    return high
