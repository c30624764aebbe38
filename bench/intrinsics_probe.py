"""Does beer lose to its cameras' intrinsics? Two copies of the capture on one common pinhole camera.

Issue 27 (round 14): beer's `poses_bounds.npy` gives every photo camera 1's focal length and no distortion, while
the COLMAP model beside it fitted one SIMPLE_RADIAL camera per photo (f 1101-1155 px, k -0.02..+0.10). Each photo
is resampled onto one pinhole camera (the file's focal length times the smallest zoom that leaves no blank pixel in
any photo), once from COLMAP's per-photo f and k ("test") and once from the single f without distortion, as the
LLFF reader reads it ("control"); both crop the same band at the image's edge, so their scores differ only by the
intrinsics. Writes WORK/beer_test and WORK/beer_control (PNG images + poses_bounds.npy); score them with

    python3 bench/intrinsics_probe.py --work /tmp/probe
    insertnerf eval /tmp/probe/beer_test --views 3,10; insertnerf eval /tmp/probe/beer_control --views 3,10
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import pycolmap

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"


def opencv_K(f: float, cx: float, cy: float) -> np.ndarray:
    """Pinhole K with OpenCV's pixel centres (at integers; COLMAP's and ours are at +0.5)."""
    return np.array([[f, 0.0, cx - 0.5], [0.0, f, cy - 0.5], [0.0, 0.0, 1.0]])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capture", type=Path, default=REALDATA / "beer")
    parser.add_argument("--work", type=Path, required=True, help="folder for the two scene copies")
    args = parser.parse_args()
    rec = pycolmap.Reconstruction(str(args.capture / "sparse" / "0"))
    camera_of = {im.name: rec.cameras[im.camera_id] for im in rec.images.values()}
    rows = np.load(args.capture / "poses_bounds.npy")
    names = sorted(p.name for p in (args.capture / "images").iterdir())
    f_file = float(rows[0, 14])  # [H, W, f] is the 3x5 matrix's last column: index 14 is f
    # A photo of focal f and radial k covers the common camera's corner when f_file * zoom >= f (1 + k r^2).
    zoom = 1.005 * max(max(1.0, c.params[0] / f_file * (1 + c.params[3] * (c.params[1] ** 2 + c.params[2] ** 2)
                                                        / f_file ** 2)) for c in camera_of.values())
    print(f"common camera: f {f_file:.1f} x {zoom:.4f}")
    for variant in ("test", "control"):
        out = args.work / f"beer_{variant}"
        (out / "images").mkdir(parents=True, exist_ok=True)
        for name in names:
            f, cx, cy, k = camera_of[name].params
            f_photo, k_photo = (f, k) if variant == "test" else (f_file, 0.0)
            img = cv2.imread(str(args.capture / "images" / name))
            flat = cv2.undistort(img, opencv_K(f_photo, cx, cy), np.array([k_photo, 0.0, 0.0, 0.0]),
                                 newCameraMatrix=opencv_K(f_file * zoom, cx, cy))
            cv2.imwrite(str(out / "images" / (Path(name).stem + ".png")), flat)
        copy = rows.copy()
        copy[:, 14] = f_file * zoom
        np.save(out / "poses_bounds.npy", copy)
        print(f"{variant}: {len(names)} images in {out}")


if __name__ == "__main__":
    main()
