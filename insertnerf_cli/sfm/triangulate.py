"""Sparse points for a posed scene that came without them (a `transforms.json` or `poses_bounds.npy` alone): COLMAP's
SIFT keypoints (sfm/features.py), matched along the known epipolar lines between each view and its nearest views
(sfm/epipolar.py), joined into tracks and triangulated at the scene's own poses (sfm/tracks.py). Render and eval
guide their fine samples by such points (depth_prior); the poses are never changed.
"""
from __future__ import annotations

import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import pycolmap
import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.scenes.points import ScenePoints
from insertnerf_cli.scenes.views import nearest_views, view_rule
from insertnerf_cli.sfm.epipolar import ViewFeatures, epipolar_matches
from insertnerf_cli.sfm.features import MAX_FEATURES, MAX_IMAGE_SIZE, PEAK_THRESHOLD, FeatureOptions, photo_features
from insertnerf_cli.sfm.points_cache import cache_file, cache_key, load_points, save_points
from insertnerf_cli.sfm.tracks import triangulate_tracks

# Each view is matched with this many of its nearest views (view_rule of the layout): a point then has the
# observers it needs (MIN_OBSERVERS) without the cost of every pair (a 100-view capture: 800 pairs, not 4,950).
NEIGHBOURS = 8
# Image pairs matched at once, each on one torch thread: much of a pair's work (gathers, nonzero) runs on one
# thread however many torch has, so pairs side by side use two cores better than one pair on two (1.7x:
# docs/research-log.md, Poses and triangulation).
MATCH_WORKERS = 2


@dataclass(frozen=True)
class TriangulateOptions:
    """How `triangulate_points` works: pairs per view, and the photos' SIFT (sfm/features.FeatureOptions: its long
    side, contrast threshold, keypoints kept per photo, CPU threads for extraction, -1: all)."""

    neighbours: int = NEIGHBOURS
    max_image_size: int = MAX_IMAGE_SIZE
    peak_threshold: float = PEAK_THRESHOLD
    max_features: int = MAX_FEATURES
    num_threads: int = -1

    @property
    def features(self) -> FeatureOptions:
        return FeatureOptions(self.max_image_size, self.peak_threshold, self.max_features, self.num_threads)


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
    except (RuntimeError, ValueError, OSError) as error:  # the render goes on without the prior
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
    """(the points of the ``chosen`` views, how many image pairs were matched)."""
    features = photo_features([scene.image_paths[i] for i in chosen], scene.root, options.features)
    w2c = scene.cameras.w2c.double().cpu().numpy()
    views = [ViewFeatures.of_photo(_photo_camera(scene, index), found.xy, found.descriptors, w2c[index, :3, :4])
             for index, found in zip(chosen, features)]
    pairs = _neighbour_pairs(scene.cameras.subset(chosen), scene.layout, options.neighbours)
    tracks = triangulate_tracks(views, _matches(views, pairs))
    # Views outside ``chosen`` observe nothing.
    observed = [torch.zeros(0, dtype=torch.long) for _ in range(len(scene))]
    for view, rows in zip(chosen, tracks.observed):
        observed[view] = torch.from_numpy(rows)
    return ScenePoints(torch.from_numpy(tracks.xyz), tuple(observed) if len(tracks.xyz) else None), len(pairs)


def _matches(views: list[ViewFeatures], pairs: list[tuple[int, int]]) -> dict[tuple[int, int], np.ndarray]:
    """(a, b) -> [M, 2] each pair's matches along the epipolar lines, MATCH_WORKERS pairs at a time."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    pool = ThreadPoolExecutor(max_workers=MATCH_WORKERS)
    try:
        return dict(zip(pairs, pool.map(lambda pair: epipolar_matches(views[pair[0]], views[pair[1]]), pairs)))
    finally:  # on Ctrl-C too: pairs not begun are dropped, the ones in hand take a tenth of a second
        pool.shutdown(wait=True, cancel_futures=True)
        torch.set_num_threads(threads)


def _neighbour_pairs(cameras: Cameras, layout: str, neighbours: int) -> list[tuple[int, int]]:
    """Each view with its ``neighbours`` nearest views by render's rule, every pair once (a < b)."""
    method = view_rule(layout)
    pairs = set()
    for a in range(len(cameras)):
        for b in nearest_views(cameras.c2w[a], cameras.c2w, neighbours, method, exclude=[a]):
            pairs.add((min(a, b), max(a, b)))
    return sorted(pairs)


def _photo_camera(scene, index: int) -> "pycolmap.Camera":
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
    return pycolmap.Camera(model=model, width=cam.width, height=cam.height, params=params)
