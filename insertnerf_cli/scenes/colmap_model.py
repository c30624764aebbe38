"""COLMAP scenes: a sparse model (``sparse/0/`` or ``sparse/``, binary or text) with ``images/``.

Read with ``pycolmap.Reconstruction``. Registered images only, sorted by name. Poses are COLMAP's
world-to-camera (OpenCV axes). Pinhole models are used as they are; radial/OpenCV/fisheye models are
undistorted when images load (focal lengths zoomed just enough to leave no blank corner, as COLMAP's undistorter
crops); other models are refused. Near/far come from the 0.1/99.9 percentiles of the depths of the points each
image observes.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..cameras import Cameras, w2c_to_c2w
from ..errors import SceneError, first_line
from .base import Scene
from .binfiles import check_colmap_binary
from .common import ReadViews, assemble, safe_path
from .geometry import point_depths
from .images import Distortion
from .points import ScenePoints

MODEL_DIRS = ("sparse/0", "sparse")
_UNDISTORT_HINT = ("undistort the model first (`colmap image_undistorter`, or run `insertnerf poses` on the "
                   "images), then point insertnerf at the undistorted folder")


def find_model(root: Path) -> Path | None:
    """The first of sparse/0, sparse that holds cameras.bin or cameras.txt."""
    for sub in MODEL_DIRS:
        if any((root / sub / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
            return root / sub
    return None


def _distortion(model: str, params: np.ndarray, where: str) -> Distortion | None:
    """COLMAP camera model + params -> our Distortion (None for pinhole models)."""
    p = [float(x) for x in params]
    if model in ("SIMPLE_PINHOLE", "PINHOLE"):
        return None
    if model == "SIMPLE_RADIAL":
        coeffs = (p[3], 0.0, 0.0, 0.0)
    elif model == "RADIAL":
        coeffs = (p[3], p[4], 0.0, 0.0)
    elif model in ("OPENCV", "FULL_OPENCV"):
        coeffs = tuple(p[4:])  # k1 k2 p1 p2 [k3 k4 k5 k6]: the same order as cv2.undistort
    elif model == "OPENCV_FISHEYE":
        return Distortion("fisheye", tuple(p[4:8]))
    else:
        raise SceneError(f"{where}: COLMAP camera model {model} is not supported; {_UNDISTORT_HINT}")
    return Distortion("opencv", coeffs) if any(coeffs) else None


def model_points(rec, image_ids: list[int]) -> ScenePoints | None:
    """The model's 3D points and, per image of ``image_ids`` (the scene's order), the points it observes; None
    when the model has no points."""
    if rec.num_points3D() == 0:
        return None
    slot = {image_id: n for n, image_id in enumerate(image_ids)}
    seen: list[list[int]] = [[] for _ in image_ids]
    xyz = []
    for row, point in enumerate(rec.points3D.values()):  # tracks: cost grows with observations, not keypoints
        xyz.append(point.xyz)
        for element in point.track.elements:
            if element.image_id in slot:
                seen[slot[element.image_id]].append(row)
    observed = tuple(torch.tensor(rows, dtype=torch.long) for rows in seen) if any(seen) else None
    return ScenePoints(torch.from_numpy(np.stack(xyz)), observed)  # a list index into a tensor is slow


def _observed_depths(points: ScenePoints | None, cameras: Cameras) -> list[Tensor] | None:
    """Per image, depths of the 3D points it observes (without tracks: those that project into it); None without
    points."""
    if points is None:
        return None
    if points.observed is None:
        return point_depths(cameras, points.xyz)
    z_rows = cameras.w2c[:, 2]  # [N, 4]: camera depth = z_row . (x, 1)
    return [points.xyz[rows] @ z_rows[n, :3] + z_rows[n, 3] for n, rows in enumerate(points.observed)]


def read_colmap(root: Path, images: str, background: tuple[float, float, float]) -> Scene:
    import pycolmap

    model_dir = find_model(root)
    check_colmap_binary(model_dir)  # pycolmap trusts declared counts: a cut-short file could allocate without bound
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
        names = {i: im.name for i, im in rec.images.items()}  # a text model's non-UTF-8 name fails here
    except UnicodeDecodeError as err:
        raise SceneError(f"{model_dir}: an image name is not valid UTF-8 ({err.object[err.start:err.end + 8]!r}); "
                         "rename the image to a UTF-8 name and re-export the model") from None
    except Exception as err:  # noqa: BLE001 - pycolmap raises plain RuntimeError/ValueError on bad files
        raise SceneError(f"cannot read the COLMAP model in {model_dir}: {first_line(err)}; re-export the model "
                         "(or run `insertnerf poses` on the images)") from None
    # One pass over the images: each rec.images[i] look-up costs a walk over that image's keypoints.
    registered = sorted(((names[i], i, im) for i, im in rec.images.items() if im.has_pose), key=lambda x: x[0])
    if not registered:
        raise SceneError(f"{model_dir}: the COLMAP model has no registered images")
    image_ids = [i for _, i, _ in registered]
    paths, Ks, w2c, sizes, dists = [], [], [], [], []
    for name, _, im in registered:
        cam = rec.cameras[im.camera_id]
        paths.append(safe_path(root, Path(images) / name, "image name"))
        dists.append(_distortion(cam.model.name, np.asarray(cam.params), f"{model_dir} camera {im.camera_id}"))
        Ks.append(torch.from_numpy(np.asarray(cam.calibration_matrix(), dtype=np.float64)))
        sizes.append((int(cam.height), int(cam.width)))
        pose = torch.eye(4, dtype=torch.float64)
        pose[:3] = torch.from_numpy(np.asarray(im.cam_from_world().matrix(), dtype=np.float64))
        w2c.append(pose)
    K, c2w = torch.stack(Ks), w2c_to_c2w(torch.stack(w2c))
    declared = Cameras(K, c2w, sizes[0][0], sizes[0][1])  # projection only needs K and poses
    points = model_points(rec, image_ids)
    views = ReadViews(root=root, paths=paths, K=K, c2w=c2w, format="colmap", sizes=sizes,
                      depths=_observed_depths(points, declared), points=points,
                      distortion=dists if any(d is not None for d in dists) else None, source=model_dir)
    return assemble(views, background)
