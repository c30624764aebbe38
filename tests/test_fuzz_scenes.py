"""Damaged scene files: every reader validates before it trusts (issue 29).

The exact damages a hostile user found (a .npy header that no longer parses, flipped bytes in a DTU cameras.npz,
a non-UTF-8 name in COLMAP's images.bin, cameras.bin and points3D.bin cut short), then a short seeded fuzz of every
format with scene_fuzz.py (bench/fuzz_scenes.py runs it long; that run is in docs/benchmarks.md).
"""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from insertnerf_cli.errors import SceneError
from insertnerf_cli.scenes import load_scene
from insertnerf_cli.scenes.binfiles import load_npy
from scene_fixtures import known_scene, write_colmap, write_dtu_idr, write_llff
from scene_fuzz import fuzz


def _refused(folder: Path, *fragments: str) -> str:
    with pytest.raises(SceneError) as info:
        load_scene(folder)
    message = str(info.value)
    assert "\n" not in message and len(message) < 400, message
    for fragment in fragments:
        assert fragment in message, message
    return message


def test_npy_with_a_damaged_header_is_one_line(tmp_path: Path) -> None:
    root = write_llff(tmp_path / "llff", known_scene())
    path = root / "poses_bounds.npy"
    data = bytearray(path.read_bytes())
    data[data.index(b"'shape'") + 10] = ord("(")  # an unclosed tuple: numpy's own parser raised tokenize.TokenError
    path.write_bytes(bytes(data))
    _refused(root, "poses_bounds.npy", "damaged .npy header")


def test_npy_header_declaring_more_rows_than_held_is_refused_before_allocating(tmp_path: Path) -> None:
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (99999999999, 17), }"
    header = header.ljust(64 * ((len(header) + 11) // 64 + 1) - 11) + "\n"
    path = tmp_path / "big.npy"
    path.write_bytes(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + bytes(408))
    with pytest.raises(SceneError, match=r"declares a \[99999999999, 17\] float64 array .* holds 408 bytes"):
        load_npy(path)


def test_npz_with_flipped_bytes_is_one_line(tmp_path: Path) -> None:
    root = write_dtu_idr(tmp_path / "dtu", known_scene())
    path = root / "cameras.npz"
    data = bytearray(path.read_bytes())
    for at in range(200, 260):  # inside the first member's data: its CRC (and, compressed, zlib) then fails
        data[at] ^= 0x5A
    path.write_bytes(bytes(data))
    _refused(root, "cameras.npz")


def test_compressed_npz_with_flipped_bytes_is_one_line(tmp_path: Path) -> None:
    root = write_dtu_idr(tmp_path / "dtu", known_scene())
    path = root / "cameras.npz"
    arrays = dict(np.load(path))
    np.savez_compressed(path, **arrays)
    data = bytearray(path.read_bytes())
    for at in range(60, 90):  # deflate data of the first member: zlib.error before
        data[at] ^= 0xFF
    path.write_bytes(bytes(data))
    _refused(root, "cameras.npz", "damaged .npz archive")


def _colmap(tmp_path: Path) -> Path:
    return write_colmap(tmp_path / "colmap", known_scene())


def test_colmap_image_name_that_is_not_utf8_is_one_line(tmp_path: Path) -> None:
    root = _colmap(tmp_path)
    path = root / "sparse" / "0" / "images.bin"
    data = path.read_bytes()
    path.write_bytes(data.replace(b"view_001", b"view\xe9001", 1))
    _refused(root, "images.bin", "not valid UTF-8")


def test_colmap_cameras_bin_cut_short_is_refused_not_read_as_a_wrong_camera(tmp_path: Path) -> None:
    root = _colmap(tmp_path)
    path = root / "sparse" / "0" / "cameras.bin"
    assert path.stat().st_size == 64
    path.write_bytes(path.read_bytes()[:54])
    _refused(root, "cameras.bin", "cut short")


def test_colmap_points_bin_cut_short_is_refused_before_allocating(tmp_path: Path) -> None:
    root = _colmap(tmp_path)
    path = root / "sparse" / "0" / "points3D.bin"
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * 0.85)])
    _refused(root, "points3D.bin", "cut short")
    # A count flipped to a huge number: refused from the byte count, never allocated (pycolmap asked for 24 GB).
    path.write_bytes(struct.pack("<Q", 2**40) + data[8:])
    _refused(root, "points3D.bin", "the point count (1099511627776) needs")


def test_colmap_bytes_after_the_records_are_refused(tmp_path: Path) -> None:
    root = _colmap(tmp_path)
    path = root / "sparse" / "0" / "images.bin"
    path.write_bytes(path.read_bytes() + b"\0" * 8)
    _refused(root, "images.bin", "8 bytes follow")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["blender", "nerfstudio", "llff", "colmap-bin", "colmap-text", "dtu-idr",
                                  "dtu-mvsnet"])
def test_seeded_fuzz_of_each_format_never_fails(name: str) -> None:
    outcomes = fuzz([name], variants=8, first_seed=1000)
    failures = [o for o in outcomes if o.failed]
    assert not failures, failures
    assert {o.verdict for o in outcomes} <= {"loaded", "refused"}
    assert any(o.verdict == "refused" for o in outcomes)  # the damage reached a reader


def test_png_with_a_damaged_header_is_refused_before_the_decoder_allocates(tmp_path: Path) -> None:
    from insertnerf_cli.scenes import read_rgb

    path = tmp_path / "a.png"
    assert cv2.imwrite(str(path), np.zeros((24, 32, 3), np.uint8))
    intact = path.read_bytes()
    idat = intact.index(b"IDAT") - 4
    bit_depth = bytearray(intact)
    bit_depth[24] ^= 0x12  # IHDR's bit depth: OpenCV allocated 1 GB for this 24x32 image
    idat_length = bytearray(intact)
    idat_length[idat:idat + 4] = (1 << 30).to_bytes(4, "big")  # an IDAT of 1 GiB: OpenCV allocated it
    for damaged in (bit_depth, idat_length):
        path.write_bytes(bytes(damaged))
        with pytest.raises(SceneError, match="damaged PNG"):
            read_rgb(path)
    huge = bytearray(intact)
    huge[16:24] = struct.pack(">II", 1 << 16, 1 << 14)  # 2^30 pixels declared, its checksum made valid again
    huge[29:33] = zlib.crc32(bytes(huge[12:29])).to_bytes(4, "big")
    path.write_bytes(bytes(huge))
    with pytest.raises(SceneError, match=r"declares \d+\+ megapixels, over 268"):
        read_rgb(path)
    path.write_bytes(intact)
    assert read_rgb(path).shape == (24, 32, 3)
