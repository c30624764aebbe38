"""Binary scene files checked before anything trusts them: .npy, .npz and COLMAP's *.bin models.

Every count or shape a file declares is compared with the bytes it really holds *before* anything is allocated
from it: a damaged or cut-short file is one SceneError naming the file and what is wrong, never a traceback, a
silently wrong camera or an allocation without bound (a flipped count in points3D.bin asked pycolmap for 24 GB).
"""
from __future__ import annotations

import ast
import io
import math
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np

from insertnerf_cli.errors import SceneError, first_line, os_error_message

_NPY_MAGIC = b"\x93NUMPY"
_MAX_HEADER = 65536


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as err:
        raise SceneError(os_error_message(err)) from None


# --------------------------------------------------------------------------------------------------- numpy
def _npy_array(data: bytes, where: str) -> np.ndarray:
    """Parse one .npy image held in ``data`` (the header by hand: its shape is checked before allocating)."""
    if len(data) < 10 or not data.startswith(_NPY_MAGIC):
        raise SceneError(f"{where} is not a .npy array (no NUMPY signature); re-create the file")
    major = data[6]
    size_len = {1: 2, 2: 4, 3: 4}.get(major)
    if size_len is None:
        raise SceneError(f"{where}: unknown .npy version {major}; re-create the file")
    start = 8 + size_len
    header_len = int.from_bytes(data[8:start], "little")
    if header_len > _MAX_HEADER or start + header_len > len(data):
        raise SceneError(f"{where}: its header declares {header_len} bytes but the file holds {len(data) - start} "
                         "after the signature: the file is cut short or damaged")
    try:
        header = ast.literal_eval(data[start:start + header_len].decode("latin1" if major < 3 else "utf-8"))
        dtype = np.dtype(header["descr"])
        shape = tuple(int(n) for n in header["shape"])
        fortran = bool(header["fortran_order"])
    except Exception as err:  # noqa: BLE001 - a damaged header raises anything literal_eval/np.dtype can
        raise SceneError(f"{where}: damaged .npy header ({type(err).__name__}); re-create the file") from None
    if dtype.hasobject or any(n < 0 for n in shape):
        raise SceneError(f"{where}: the header declares {'Python objects' if dtype.hasobject else 'a negative size'}"
                         "; insertnerf reads plain numeric arrays only")
    declared = math.prod(shape) * dtype.itemsize
    held = len(data) - start - header_len
    if declared != held:
        raise SceneError(f"{where}: its header declares a {list(shape)} {dtype} array ({declared} bytes) but the "
                         f"file holds {held} bytes of data: the file is cut short or damaged; re-create it")
    flat = np.frombuffer(data, dtype=dtype, count=math.prod(shape), offset=start + header_len)
    return flat.reshape(shape, order="F" if fortran else "C").copy()


def load_npy(path: Path) -> np.ndarray:
    """A plain numeric array from a .npy file, checked (no pickles: the file is data, not code)."""
    return _npy_array(_read_bytes(path), str(path))


def load_npz(path: Path) -> dict[str, np.ndarray]:
    """Every array of a .npz archive, each checked against the size its zip entry declares."""
    data = _read_bytes(path)
    arrays = {}
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            for info in archive.infolist():
                if not info.filename.endswith(".npy"):
                    continue
                if info.file_size > 64 * max(info.compress_size, 1 << 20):  # far more than npz data compresses
                    raise SceneError(f"{path}: entry {info.filename} declares {info.file_size} bytes from "
                                     f"{info.compress_size} compressed: the archive is damaged")
                arrays[info.filename[:-4]] = _npy_array(archive.read(info), f"{path} entry {info.filename}")
    except SceneError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, EOFError, ValueError, NotImplementedError,
            UnicodeDecodeError, KeyError, OverflowError, struct.error, OSError) as err:
        detail = first_line(err, 120)  # zipfile quotes whole damaged names
        raise SceneError(f"cannot read {path}: damaged .npz archive ({type(err).__name__}: {detail!r}); "
                         "re-create the file") from None
    return arrays


# -------------------------------------------------------------------------------------------- COLMAP models
# Parameters per COLMAP camera model id (colmap/sensor/models.h).
_CAMERA_PARAMS = {0: 3, 1: 4, 2: 4, 3: 5, 4: 8, 5: 8, 6: 12, 7: 5, 8: 4, 9: 5, 10: 12, 11: 16, 12: 4, 13: 5,
                  14: 3, 15: 4, 16: 6, 17: 0}


class _Cursor:
    """Reads little-endian records from ``data``, refusing to pass its end."""

    def __init__(self, data: bytes, path: Path):
        self.data, self.path, self.at = data, path, 0

    def need(self, count: int, size: int, what: str) -> None:
        """Refuse ``count`` records of ``size`` bytes that the bytes left cannot hold (before allocating)."""
        left = len(self.data) - self.at
        if count * size > left:
            raise SceneError(f"{self.path}: {what} needs {count} x {size} bytes but only {left} are left: the file "
                             "is cut short or damaged; re-export the model")

    def take(self, fmt: str, what: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        self.need(1, size, what)
        values = struct.unpack_from("<" + fmt, self.data, self.at)
        self.at += size
        return values

    def skip(self, count: int, size: int, what: str) -> None:
        self.need(count, size, what)
        self.at += count * size

    def name(self, what: str) -> str:
        end = self.data.find(b"\0", self.at)
        if end < 0:
            raise SceneError(f"{self.path}: {what} has no end (cut short or damaged); re-export the model")
        raw, self.at = self.data[self.at:end], end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise SceneError(f"{self.path}: {what} {raw!r} is not valid UTF-8; rename the image to a UTF-8 name "
                             "and re-export the model") from None

    def finish(self) -> None:
        if self.at != len(self.data):
            raise SceneError(f"{self.path}: {len(self.data) - self.at} bytes follow its declared records: the file "
                             "is damaged (a wrong count?); re-export the model")


def _cameras(c: _Cursor) -> set[int]:
    (count,) = c.take("Q", "the camera count")
    c.need(count, 24, f"the camera count ({count})")
    ids = set()
    for n in range(count):
        camera_id, model, width, height = c.take("iiQQ", f"camera {n}")
        if model not in _CAMERA_PARAMS or not (0 < width < 1 << 20 and 0 < height < 1 << 20):
            raise SceneError(f"{c.path}: camera {camera_id} has an unknown model id {model} or a size of "
                             f"{width}x{height}: the file is damaged; re-export the model")
        params = c.take(f"{_CAMERA_PARAMS[model]}d", f"camera {camera_id}'s parameter block")
        if not all(math.isfinite(p) for p in params):
            raise SceneError(f"{c.path}: camera {camera_id} has non-finite parameters; re-export the model")
        ids.add(camera_id)
    return ids


def _images(c: _Cursor, cameras: set[int]) -> None:
    (count,) = c.take("Q", "the image count")
    c.need(count, 64 + 1 + 8, f"the image count ({count})")
    for n in range(count):
        image_id, *pose, camera_id = c.take("I7di", f"image {n}")
        c.name(f"image {image_id}'s name")
        if not all(math.isfinite(p) for p in pose) or camera_id not in cameras:
            raise SceneError(f"{c.path}: image {image_id} has a non-finite pose or an unknown camera {camera_id}: "
                             "the file is damaged; re-export the model")
        (points,) = c.take("Q", f"image {image_id}'s keypoint count")
        c.skip(points, 24, f"image {image_id}'s keypoints ({points})")


def _headed_records(c: _Cursor, what: str, head: str, tail_count: str, tail_item: int, tail: str) -> None:
    """A count, then records of a fixed ``head`` and a counted ``tail`` of ``tail_item``-byte items each."""
    (count,) = c.take("Q", f"the {what} count")
    c.need(count, struct.calcsize("<" + head + tail_count), f"the {what} count ({count})")
    for n in range(count):
        record_id, *_ = c.take(head, f"{what} {n}")
        (items,) = c.take(tail_count, f"{what} {record_id}'s {tail}")
        c.skip(items, tail_item, f"{what} {record_id}'s {tail} ({items})")


def _points(c: _Cursor) -> None:
    _headed_records(c, "point", "Q3d3Bd", "Q", 8, "track")  # id, xyz, rgb, error; track of (image id, keypoint index)


def _rigs(c: _Cursor) -> None:
    (count,) = c.take("Q", "the rig count")
    c.need(count, 8, f"the rig count ({count})")
    for n in range(count):
        rig_id, sensors = c.take("II", f"rig {n}")
        if sensors:
            c.take("iI", f"rig {rig_id}'s reference sensor")
        c.need(sensors - 1 if sensors else 0, 9, f"rig {rig_id}'s sensor count")
        for _ in range(max(sensors - 1, 0)):
            *_, has_pose = c.take("iIB", f"rig {rig_id}'s sensor")
            if has_pose:
                c.take("7d", f"rig {rig_id}'s sensor pose")


def _frames(c: _Cursor) -> None:
    # id, rig id, pose; data of (sensor type, sensor id, data id)
    _headed_records(c, "frame", "II7d", "I", 16, "data list")


def check_colmap_binary(model_dir: Path) -> None:
    """Walk every record of a binary COLMAP model (cameras, images, points3D, and rigs/frames when present)
    before pycolmap reads it; image names must be UTF-8.

    Raises:
        SceneError: a file cut short, a count its bytes cannot hold, bytes after the records, an unknown camera
            model, a non-finite camera or pose, an image naming an unknown camera, or a non-UTF-8 image name.
    """
    if not (model_dir / "cameras.bin").is_file():
        return  # a text model: pycolmap's text reader checks its own lines
    for name, walk in (("rigs.bin", _rigs), ("frames.bin", _frames)):
        if (model_dir / name).is_file():
            cursor = _Cursor(_read_bytes(model_dir / name), model_dir / name)
            walk(cursor)
            cursor.finish()
    cursor = _Cursor(_read_bytes(model_dir / "cameras.bin"), model_dir / "cameras.bin")
    cameras = _cameras(cursor)
    cursor.finish()
    for name in ("images.bin", "points3D.bin"):
        path = model_dir / name
        if not path.is_file():
            raise SceneError(f"{model_dir}: cameras.bin without {name}; re-export the whole model")
        cursor = _Cursor(_read_bytes(path), path)
        _images(cursor, cameras) if name == "images.bin" else _points(cursor)
        cursor.finish()
