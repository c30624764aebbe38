"""Sparse points for a posed scene that came without them (a `transforms.json` or `poses_bounds.npy` alone):
COLMAP's SIFT features, matched between each view and its nearest views, triangulated at the scene's own poses
(pycolmap.triangulate_points, COLMAP's `point_triangulator`). Render and eval guide their fine samples by such
points (depth_prior); the poses are never changed.
"""
from __future__ import annotations

import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

import pycolmap
import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.poses.child import run_in_child
from insertnerf_cli.poses.estimate import pycolmap_log
from insertnerf_cli.poses.folder import colmap_readable
from insertnerf_cli.poses.reconstruction import cam_from_world
from insertnerf_cli.scenes.colmap_model import model_points
from insertnerf_cli.scenes.images import exif_orientation
from insertnerf_cli.scenes.points import ScenePoints
from insertnerf_cli.scenes.views import nearest_views, view_rule
from insertnerf_cli.sfm.epipolar import epipolar_matches, view_features
from insertnerf_cli.sfm.points_cache import cache_file, cache_key, load_points, save_points

# Each view is matched with this many of its nearest views (view_rule of the layout): a point then has the
# observers it needs (MIN_OBSERVERS) without the cost of every pair (a 100-view capture: 800 pairs, not 4,950).
NEIGHBOURS = 8
# SIFT on images no larger than this: the points guide samples to within a few per cent of depth, which 768 px
# keypoints locate well enough; extraction and matching cost about half of 1024 px's. Smaller images lost points,
# and with them 0.2-0.5 dB at 3 views (measured: docs/research-log.md, Poses and triangulation).
MAX_IMAGE_SIZE = 768
# COLMAP's RANSAC and triangulator draw at random: a fixed seed and a one-thread triangulator (its bundle
# adjustment) make the points repeatable in most runs. Feature extraction and matching keep their threads (a
# third less time than with one), and with them a run can still differ a little: a few points in a thousand, which
# moves eval's scores by 0.01 dB or less (measured: docs/research-log.md, Poses and triangulation).
RANDOM_SEED = 0
ORDERED_THREADS = 1
# SIFT's contrast threshold, well below COLMAP's 1/150: the keypoints on faint texture (tissue, a plain wooden box,
# a lab's far wall) that matching along the epipolar lines can place; at 768 px it also makes up the keypoints the
# smaller images lose (measured: docs/research-log.md, Poses and triangulation).
PEAK_THRESHOLD = 0.001


@dataclass(frozen=True)
class TriangulateOptions:
    """How `triangulate_points` works: pairs per view, SIFT image size, CPU threads for feature extraction and
    COLMAP's matching (-1: all; the epipolar matcher runs on torch's threads), matches searched along the known
    epipolar lines (sfm/epipolar.py; False: COLMAP's matcher, which knows no poses, and its RANSAC), SIFT's
    contrast threshold, and at most this many SIFT features per image (the strongest)."""

    neighbours: int = NEIGHBOURS
    max_image_size: int = MAX_IMAGE_SIZE
    num_threads: int = -1
    along_epipolar_lines: bool = True
    peak_threshold: float = PEAK_THRESHOLD
    max_num_features: int = 8192


def with_points(scene, views: Sequence[int] | None = None, cache: Path | None = None,
                claim: Callable[[Path], None] | None = None, options: TriangulateOptions = TriangulateOptions()):
    """``scene`` itself when it has SfM points, else the scene with points triangulated from ``views`` at its
    poses; unchanged, saying so on the progress line (or on one warning line when COLMAP fails), when it finds
    none (too few features, images too small). With a ``cache`` folder (sfm/points_cache.py), points an earlier
    run triangulated from the same photos, poses and views are loaded instead, and new ones are written there
    (``claim`` is told each file's path before it is written, so that the output's record holds it)."""
    if scene.points is not None:
        return scene
    chosen = sorted(set(range(len(scene)) if views is None else views))
    stored = None if cache is None else cache_file(cache, cache_key(scene, chosen, options))
    if stored is not None and (points := load_points(stored, len(scene))) is not None:
        print(f"SfM points: {len(points)} loaded from {stored}, triangulated by an earlier run from the same photos "
              "and poses", file=sys.stderr, flush=True)
        return replace(scene, points=points) if len(points) else scene
    try:
        points = triangulate_points(scene, chosen, options)
    except (RuntimeError, ValueError, OSError) as error:  # pycolmap's failures: the render goes on without
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        print(f"warning: no SfM points could be triangulated at the scene's poses ({reason}); going on "
              "without the depth prior.", file=sys.stderr, flush=True)
        return scene
    if stored is not None:
        if claim is not None:
            claim(stored)
        stored.parent.mkdir(parents=True, exist_ok=True)
        save_points(stored, points, len(scene))
    return replace(scene, points=points) if len(points) else scene  # triangulate_points' line said so


def triangulate_points(scene, views: Sequence[int] | None = None,
                       options: TriangulateOptions = TriangulateOptions(), quiet: bool = False) -> ScenePoints:
    """The scene's sparse points, triangulated from ``views`` (default: all) at the scene's poses.

    Args:
        scene: a loaded Scene (scenes.base.Scene) whose image files are the photos its cameras describe.
        views: indices of the views that may observe points (eval passes its references only, so that a held-out
            photo lends nothing to its own render).
    Returns:
        ScenePoints in the scene's world, with each view's observations (empty for views outside ``views``).
    """
    chosen = sorted(set(range(len(scene)) if views is None else views))
    if len(chosen) < 2:
        raise ValueError(f"{len(chosen)} view(s) cannot triangulate a point")
    started = time.perf_counter()
    if not quiet:  # one line, finished when the points are: a failure's message then stands on its own lines
        print(f"triangulating SfM points at the scene's poses from {len(chosen)} views (the scene came without "
              "them; --no-sfm-depth skips this) ...", end="", file=sys.stderr, flush=True)
    try:
        points, pairs = _triangulate(scene, chosen, options)
    except BaseException:
        if not quiet:
            print(file=sys.stderr, flush=True)
        raise
    if not quiet:  # no point (plain or tiny photos) is said on the same line: one line in all
        found = f"{len(points)} points" if len(points) else "no point seen by two views"
        print(f" {found} ({pairs} image pairs, {time.perf_counter() - started:.0f} s)"
              + ("" if len(points) else "; going on without the depth prior."), file=sys.stderr, flush=True)
    return points


def _triangulate(scene, chosen: list[int], options: TriangulateOptions) -> tuple[ScenePoints, int]:
    """(the points of the ``chosen`` views, how many image pairs were matched): COLMAP in a temporary folder."""
    with tempfile.TemporaryDirectory(prefix="insertnerf-triangulate-") as tmp, pycolmap_log(False):
        work = Path(tmp)
        folder, names = _colmap_images([scene.image_paths[i] for i in chosen], scene.root, work / "images")
        db_path = work / "database.db"
        _extract(folder, names, db_path, options)
        ids = _database_ids(db_path, names)
        pairs = _neighbour_pairs(scene.cameras.subset(chosen), scene.layout, options.neighbours)
        rec = _posed_model(scene, chosen, names, ids, db_path)
        if options.along_epipolar_lines:
            _match_along_epipolar_lines(rec, db_path, [(ids[names[a]][0], ids[names[b]][0]) for a, b in pairs])
        else:
            _match_with_colmap(work, db_path, [(names[a], names[b]) for a, b in pairs], options)
        (work / "model").mkdir()
        triangulation = pycolmap.IncrementalPipelineOptions(num_threads=ORDERED_THREADS, random_seed=RANDOM_SEED)
        posed = rec

        def triangulate(send: Callable[[object], None]) -> None:  # in a child process: Ctrl-C stops it at once
            pycolmap.triangulate_points(posed, db_path, folder, work / "model", clear_points=True,
                                        options=triangulation).write(work / "model")

        run_in_child(triangulate)
        rec = pycolmap.Reconstruction(work / "model")
    # Views outside ``chosen`` are in no model: an id no image has leaves their observations empty.
    image_ids = [pycolmap.INVALID_IMAGE_ID] * len(scene)
    for view, name in zip(chosen, names):
        image_ids[view] = ids[name][0]
    points = model_points(rec, image_ids)
    return (points if points is not None else ScenePoints(torch.zeros(0, 3, dtype=torch.float64))), len(pairs)


def _match_with_colmap(work: Path, db_path: Path, pairs: list[tuple[str, str]], options: TriangulateOptions) -> None:
    (work / "pairs.txt").write_text("".join(f"{a} {b}\n" for a, b in pairs))
    matching = pycolmap.FeatureMatchingOptions(num_threads=options.num_threads)
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = RANDOM_SEED
    pairing = pycolmap.ImportedPairingOptions(match_list_path=str(work / "pairs.txt"))
    run_in_child(lambda send: pycolmap.match_image_pairs(db_path, matching_options=matching, pairing_options=pairing,
                                                         verification_options=verification,
                                                         device=pycolmap.Device.cpu))


def _match_along_epipolar_lines(rec: "pycolmap.Reconstruction", db_path: Path, pairs: list[tuple[int, int]]) -> None:
    """Writes each image pair's matches along the epipolar lines of the model's poses (epipolar.py) into the
    database, as the verified matches the triangulator reads."""
    features = {}
    with pycolmap.Database.open(db_path) as db:
        for image_id in sorted({i for pair in pairs for i in pair}):
            image = rec.images[image_id]
            features[image_id] = view_features(rec.cameras[image.camera_id], db.read_keypoints(image_id),
                                               db.read_descriptors(image_id).data, cam_from_world(image))
        for a, b in pairs:
            first, second = min(a, b), max(a, b)
            matches = epipolar_matches(features[first], features[second])
            geometry = pycolmap.TwoViewGeometry(config=pycolmap.TwoViewGeometryConfiguration.CALIBRATED,
                                                inlier_matches=matches)
            db.write_matches(first, second, matches)
            db.write_two_view_geometry(first, second, geometry)


def _colmap_images(paths: list[Path], root: Path, copies: Path) -> tuple[Path, list[str]]:
    """(the folder COLMAP reads, each image's name in it), as `insertnerf poses` hands photos to COLMAP (WebP
    decoded, EXIF rotation applied, names made UTF-8), so that the keypoints lie in the pixels the cameras
    describe."""
    folder, names = colmap_readable(paths, {p for p in paths if exif_orientation(p) != 1}, root, copies)
    return folder, list(names)


def _extract(root: Path, names: list[str], db_path: Path, options: TriangulateOptions) -> None:
    extraction = pycolmap.FeatureExtractionOptions(max_image_size=options.max_image_size,
                                                   num_threads=options.num_threads)
    extraction.sift.peak_threshold = options.peak_threshold
    extraction.sift.max_num_features = options.max_num_features
    run_in_child(lambda send: pycolmap.extract_features(db_path, root, image_names=names,
                                                        camera_mode=pycolmap.CameraMode.PER_IMAGE,
                                                        extraction_options=extraction, device=pycolmap.Device.cpu))


def _database_ids(db_path: Path, names: list[str]) -> dict[str, tuple[int, int]]:
    """Image name -> (image id, camera id) as feature extraction wrote them."""
    with pycolmap.Database.open(db_path) as db:
        ids = {img.name: (int(img.image_id), int(img.camera_id)) for img in db.read_all_images()}
    missing = [n for n in names if n not in ids]
    if missing:
        raise RuntimeError(f"COLMAP read no features from {len(missing)} images (first: {missing[0]})")
    return ids


def _neighbour_pairs(cameras: Cameras, layout: str, neighbours: int) -> list[tuple[int, int]]:
    """Each view with its ``neighbours`` nearest views by render's rule, every pair once (a < b)."""
    method = view_rule(layout)
    pairs = set()
    for a in range(len(cameras)):
        for b in nearest_views(cameras.c2w[a], cameras.c2w, neighbours, method, exclude=[a]):
            pairs.add((min(a, b), max(a, b)))
    return sorted(pairs)


def _colmap_camera(scene, index: int, camera_id: int) -> "pycolmap.Camera":
    """The photo's own camera: the scene's pinhole, or with the lens distortion its loader removes."""
    cam = scene.cameras.subset([index])
    fx, fy, cx, cy = (float(v) for v in (cam.K[0, 0, 0], cam.K[0, 1, 1], cam.K[0, 0, 2], cam.K[0, 1, 2]))
    distortion = scene.distortion[index] if scene.distortion is not None else None
    if distortion is None:
        model, params = "PINHOLE", [fx, fy, cx, cy]
    else:  # the loader zooms the undistorted pinhole by `zoom`: the photo's focal lengths are the pinhole's / zoom
        fx, fy = fx / distortion.zoom, fy / distortion.zoom
        coeffs = list(distortion.coeffs)
        if distortion.model == "fisheye":
            model, params = "OPENCV_FISHEYE", [fx, fy, cx, cy] + (coeffs + [0.0] * 4)[:4]
        elif len(coeffs) <= 4:
            model, params = "OPENCV", [fx, fy, cx, cy] + (coeffs + [0.0] * 4)[:4]
        else:
            model, params = "FULL_OPENCV", [fx, fy, cx, cy] + (coeffs + [0.0] * 8)[:8]
    return pycolmap.Camera(model=model, width=cam.width, height=cam.height, params=params, camera_id=camera_id)


def _posed_model(scene, chosen: list[int], names: list[str], ids: dict[str, tuple[int, int]],
                 db_path: Path) -> "pycolmap.Reconstruction":
    """A COLMAP model of the chosen views at the scene's poses, with the database's image and camera ids (the
    database's cameras are set to the same intrinsics, which triangulation reads from both)."""
    rec = pycolmap.Reconstruction()
    w2c = scene.cameras.w2c.double().cpu().numpy()
    with pycolmap.Database.open(db_path) as db:
        for index, name in zip(chosen, names):
            image_id, camera_id = ids[name]
            camera = _colmap_camera(scene, index, camera_id)
            db.update_camera(camera)
            rec.add_camera_with_trivial_rig(camera)
            pose = pycolmap.Rigid3d(w2c[index, :3, :4])
            rec.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=camera_id, image_id=image_id),
                                             pose)
    return rec
