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

from insertnerf_cli.cameras.camera import Cameras, w2c_to_c2w
from insertnerf_cli.errors import SceneError, first_line
from insertnerf_cli.scenes.base import Scene
from insertnerf_cli.scenes.binfiles import check_colmap_binary
from insertnerf_cli.scenes.common import ReadViews, assemble, safe_path
from insertnerf_cli.scenes.geometry import point_depths
from insertnerf_cli.scenes.images import Distortion
from insertnerf_cli.scenes.points import ScenePoints

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
    import pycolmap  # deferred: its import installs glog's signal handlers

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


# Another format's cameras and a COLMAP model beside them are taken for the same solution when the model's camera
# centres map onto theirs to within this share of their spread (a different model leaves metres, not millimetres).
ALIGN_TOLERANCE = 0.01


def aligned_model_points(root: Path, c2w: Tensor, paths: list[Path]) -> ScenePoints | None:
    """The points of the COLMAP model kept beside another format's cameras (``sparse/0``, ``sparse`` or under
    ``colmap/``, as LLFF's and nerfstudio's tools leave them), moved into those cameras' world by the similarity
    that maps the model's camera centres onto the cameras' ``c2w`` [N, 4, 4] (images matched by file name), with
    the views observing each point in the cameras' order. None without such a model, with fewer than three
    matched images, or when the centres do not agree (ALIGN_TOLERANCE): the points then belong to another solution.
    """
    import pycolmap  # deferred: its import installs glog's signal handlers

    model_dir = find_model(root) or find_model(root / "colmap")
    if model_dir is None:
        return None
    try:
        check_colmap_binary(model_dir)
        rec = pycolmap.Reconstruction(str(model_dir))
        ids = {Path(im.name).name: i for i, im in rec.images.items() if im.has_pose}
    except Exception:  # noqa: BLE001 - optional: the scene's own cameras do not depend on it
        return None
    matched = [(n, ids[p.name]) for n, p in enumerate(paths) if p.name in ids]
    if len(matched) < 3:
        return None
    theirs = torch.stack([torch.from_numpy(np.asarray(rec.images[i].projection_center(), dtype=np.float64))
                          for _, i in matched])
    ours = c2w[[n for n, _ in matched], :3, 3].to(torch.float64)
    fit = fit_similarity(theirs, ours)
    if fit is None or fit[3] > ALIGN_TOLERANCE * float((ours - ours.mean(0)).norm(dim=-1).mean()):
        return None
    rotation, translation, scale, _ = fit
    points = model_points(rec, [ids.get(p.name, -1) for p in paths])
    if points is None:
        return None
    return ScenePoints(scale * points.xyz @ rotation.T + translation, points.observed)


def fit_similarity(src: Tensor, dst: Tensor) -> tuple[Tensor, Tensor, float, float] | None:
    """(R [3, 3], t [3], s, rms residual) of the similarity s R x + t that maps points ``src`` [N, 3] onto ``dst``
    [N, 3] in the least-squares sense (Umeyama 1991); None when ``src`` has no spread."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    var = float((a * a).sum(-1).mean())
    if var < 1e-18:
        return None
    u, sigma, vt = torch.linalg.svd(b.T @ a / len(src))
    sign = torch.ones(3, dtype=src.dtype)
    sign[2] = torch.sign(torch.linalg.det(u @ vt)) or 1.0
    rotation = u @ torch.diag(sign) @ vt
    scale = float((sigma * sign).sum()) / var
    translation = mu_d - scale * rotation @ mu_s
    residual = float(((scale * a @ rotation.T) - b).norm(dim=-1).pow(2).mean().sqrt())
    return rotation, translation, scale, residual
