"""What every reader shares: safe paths, and turning what a reader found into a checked ``Scene``.

A reader fills a :class:`ReadViews` (cameras at the sizes its file declares, in OpenCV axes) and calls
:func:`assemble`, which checks the image files, brings mixed sizes to one, and fills in bounds and layout.
"""
from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch
from torch import Tensor

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.errors import SceneError
from insertnerf_cli.scenes.base import Layout, Scene
from insertnerf_cli.scenes.geometry import bounds_from_depths, bounds_from_geometry, detect_layout
from insertnerf_cli.scenes.images import MAX_ZOOM, Distortion, blank_free_zoom, image_size, source_share
from insertnerf_cli.scenes.points import ScenePoints

# Two sizes share an aspect ratio when rescaling one to the other moves its height by at most this many pixels.
ASPECT_TOLERANCE_PX = 1.0
# How many missing files a message names before it says "and N more".
_NAMES_SHOWN = 3
# Values beyond these come from broken files, and break the maths after them (K inversion, normalisation):
MIN_FOCAL_PX = 1e-2  # a focal length of 0.01 pixels is a field of view of nearly 180 degrees
MAX_COORD = 1e12  # world units: camera positions and far bounds (squares stay far from float64 overflow)
# An undistorted image with less of it covered by its photo is a broken lens model, not a photo to render from.
MIN_SOURCE_SHARE = 0.5


def safe_path(root: Path, relative: str | os.PathLike, what: str = "path", source: Path | None = None) -> Path:
    """``root / relative`` normalised, refused (SceneError) when it lands outside ``root``; messages name
    ``source`` (the file the path was read from) when given, else ``root``.

    Absolute paths and ``..`` that climb out are refused. The check is on the path as written, not on
    symbolic links, so a user may still link a big ``images/`` folder into a scene.
    """
    candidate = Path(os.path.normpath(root / relative))
    if not candidate.is_relative_to(os.path.normpath(root)):
        raise SceneError(f"{source or root}: {what} {str(relative)!r} points outside the scene folder {root}; "
                         "scene files may only refer to files inside their folder")
    return candidate


@dataclass(frozen=True)
class ReadViews:
    """What a reader found, before checks. N views.

    Attributes:
        root: the scene folder.
        source: the file (or model folder) the cameras come from, named in messages (None: ``root``).
        paths: N image files (already checked with :func:`safe_path`).
        K: [N, 3, 3] intrinsics, each for the image size in ``sizes`` (or the file's size when None).
        c2w: [N, 4, 4] camera-to-world, OpenCV axes.
        format: reader name.
        sizes: N declared (height, width) that K refers to, or None to take the files' sizes.
        near, far: [N] bounds from the format, or None.
        depths: N tensors of sparse-point depths seen by each view (for bounds), or None.
        points: the sparse 3D points (structure from motion), or None.
        splits, layout, depth_paths, depth_scale, distortion: as in :class:`Scene` (layout None = detect).
    """

    root: Path
    paths: list[Path]
    K: Tensor  # [N, 3, 3]
    c2w: Tensor  # [N, 4, 4]
    format: str
    sizes: list[tuple[int, int]] | None = None
    near: Tensor | None = None  # [N]
    far: Tensor | None = None  # [N]
    depths: list[Tensor] | None = None
    points: ScenePoints | None = None
    splits: dict[str, list[int]] = field(default_factory=dict)
    layout: Layout | None = None
    depth_paths: list[Path] | None = None
    depth_scale: float = 1.0
    distortion: list[Distortion | None] | None = None
    source: Path | None = None


def names_list(paths: list[str] | list[Path]) -> str:
    """'a, b, c and 4 more' for messages."""
    shown = ", ".join(str(p) for p in paths[:_NAMES_SHOWN])
    return shown + (f" and {len(paths) - _NAMES_SHOWN} more" if len(paths) > _NAMES_SHOWN else "")


def _file_sizes(root: Path, paths: list[Path]) -> list[tuple[int, int]]:
    """(height, width) of each image file; every missing file is named in one SceneError."""
    missing = [p.relative_to(root) if p.is_relative_to(root) else p for p in paths if not p.is_file()]
    if missing:
        raise SceneError(f"{root}: {len(missing)} of {len(paths)} images listed by the scene are missing: "
                         f"{names_list(missing)}")
    return [image_size(p) for p in paths]


def _same_aspect(a: tuple[int, int], b: tuple[int, int]) -> bool:
    return abs(a[0] * b[1] / a[1] - b[0]) <= ASPECT_TOLERANCE_PX


def _scale_K(K: Tensor, src: tuple[int, int], dst: tuple[int, int]) -> Tensor:
    """K [3, 3] for an image of size src resized to dst (fx, cx by the width ratio; fy, cy by the height ratio)."""
    scale = torch.tensor([dst[1] / src[1], dst[0] / src[0], 1.0], dtype=K.dtype)
    return K * scale[:, None]


def unify_sizes(views: ReadViews) -> Cameras:
    """Cameras at one common image size: the most frequent file size (the largest on ties).

    K is first moved from the declared size to the file's size (e.g. images_4/ next to full-size cameras),
    then to the common size. Files whose aspect ratio differs from the declared or common one are refused.
    """
    files = _file_sizes(views.root, views.paths)
    declared = views.sizes or files
    K = views.K.to(torch.float64).clone()
    for i, (dec, got) in enumerate(zip(declared, files)):
        if not _same_aspect(dec, got):
            turned = " (after its EXIF rotation; the poses may come from unrotated pixels)" \
                if _same_aspect(dec, got[::-1]) else ""
            raise SceneError(f"{views.paths[i]}: image is {got[1]}x{got[0]}{turned} but its camera is for "
                             f"{dec[1]}x{dec[0]} (another aspect ratio); re-export the images or the poses")
        K[i] = _scale_K(K[i], dec, got)
    counts = Counter(files)
    common = max(counts, key=lambda s: (counts[s], s[0] * s[1]))
    odd = [views.paths[i].name for i, s in enumerate(files) if not _same_aspect(s, common)]
    if odd:
        raise SceneError(f"{views.root}: images have different aspect ratios ({len(odd)} differ from "
                         f"{common[1]}x{common[0]}: {names_list(odd)}); crop them to one aspect ratio")
    for i, got in enumerate(files):
        K[i] = _scale_K(K[i], got, common)
    return Cameras(K=K, c2w=views.c2w.to(torch.float64), height=common[0], width=common[1])


def _view_name(views: ReadViews, i: int) -> str:
    path = views.paths[i]
    return path.relative_to(views.root).as_posix() if path.is_relative_to(views.root) else str(path)


def _first_bad(ok: Tensor) -> int | None:
    """Index of the first False in a [N] bool tensor, None when all are True."""
    bad = (~ok).nonzero()
    return int(bad[0, 0]) if len(bad) else None


# Longest image side a camera may declare (a 2^17 px side is already past any single photo); more is a damaged file.
MAX_IMAGE_SIDE = 1 << 17


def check_views(views: ReadViews) -> None:
    """Refuse what no format may hold: image sizes, focal lengths or poses that are not finite and positive, or
    poses that are not rigid. They come from broken files and would poison everything after.

    Raises:
        SceneError: naming the file, the first bad view, its value and what to do.
    """
    where = views.source or views.root
    fix = "correct the file or re-export the scene (e.g. with `insertnerf poses`)"
    for i, (h, w) in enumerate(views.sizes or []):
        if not (0 < h <= MAX_IMAGE_SIDE and 0 < w <= MAX_IMAGE_SIDE):  # a damaged file may say 6e22
            raise SceneError(f"{where}: the camera of {_view_name(views, i)} is for a {w:.6g}x{h:.6g} image; width "
                             f"and height must be positive and at most {MAX_IMAGE_SIDE}; {fix}")
    K, c2w = views.K.to(torch.float64), views.c2w.to(torch.float64)
    focal = torch.stack([K[:, 0, 0], K[:, 1, 1]], dim=-1)  # [N, 2]
    i = _first_bad(torch.isfinite(K).all(dim=(1, 2)) & (focal >= MIN_FOCAL_PX).all(dim=-1))
    if i is not None:
        raise SceneError(f"{where}: the camera of {_view_name(views, i)} has focal length fx={float(focal[i, 0]):g}, "
                         f"fy={float(focal[i, 1]):g} and principal point cx={float(K[i, 0, 2]):g}, "
                         f"cy={float(K[i, 1, 2]):g}; focal lengths must be at least {MIN_FOCAL_PX:g} pixels and "
                         f"all values finite; {fix}")
    rot = c2w[:, :3, :3]
    bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
    finite = torch.isfinite(c2w).all(dim=(1, 2)) & (c2w[:, :3, 3].abs() <= MAX_COORD).all(dim=-1)
    rot = torch.where(finite[:, None, None], rot, torch.eye(3, dtype=torch.float64))  # no NaN into det()
    rigid = ((rot.transpose(1, 2) @ rot - torch.eye(3, dtype=torch.float64)).abs().amax(dim=(1, 2)) <= 1e-4) \
        & (torch.det(rot) > 0) & ((c2w[:, 3] - bottom).abs().amax(dim=-1) <= 1e-6)
    i = _first_bad(finite & rigid)
    if i is not None:
        what = (f"contains NaN, infinity or a coordinate beyond {MAX_COORD:g}" if not finite[i] else
                "is not a rigid camera pose (its rotation is scaled, mirrored or degenerate, or its last row is not "
                "0 0 0 1)")
        raise SceneError(f"{where}: the pose of {_view_name(views, i)} {what}; {fix}")


def _check_bounds(views: ReadViews, near: Tensor, far: Tensor, given: bool) -> None:
    """0 < near < far, both finite, for every view."""
    i = _first_bad(torch.isfinite(near) & (far <= MAX_COORD) & (near > 0) & (far > near))
    if i is None:
        return
    origin = f"{views.source or views.root} gives" if given else f"{views.root}: the scene's geometry gives"
    raise SceneError(f"{origin} near={float(near[i]):g}, far={float(far[i]):g} for {_view_name(views, i)}; "
                     f"they must satisfy 0 < near < far <= {MAX_COORD:g}; correct the file or re-export the scene")


def undistorted_cameras(views: ReadViews, cameras: Cameras) -> tuple[Cameras, list[Distortion | None] | None]:
    """The pinhole cameras the undistorted images will have: each distorted view zoomed (focal lengths only) just
    enough that its undistorted image has a source pixel everywhere; ``views.distortion`` with those zooms.

    Raises:
        SceneError: a lens that leaves most of the undistorted image without a source even at MAX_ZOOM (damaged
            distortion coefficients, or a fisheye beyond what a pinhole image holds).
    """
    if views.distortion is None:
        return cameras, None
    K = cameras.K.clone()  # [N, 3, 3]
    zoomed: list[Distortion | None] = []
    for i, d in enumerate(views.distortion):
        if d is not None:
            photo_K = K[i].numpy().copy()  # K[i] is scaled below
            d = replace(d, zoom=blank_free_zoom(photo_K, cameras.height, cameras.width, d))
            share = 1.0 if d.zoom < MAX_ZOOM else source_share(photo_K, cameras.height, cameras.width, d)
            K[i, :2, :2] *= d.zoom
            if share < MIN_SOURCE_SHARE:
                coeffs = ", ".join(f"{c:g}" for c in d.coeffs)
                raise SceneError(f"{views.source or views.root}: the lens distortion of {_view_name(views, i)} "
                                 f"({d.model} {coeffs}) leaves {100 * (1 - share):.0f} % of the undistorted image "
                                 f"with no source pixel; check the camera's distortion parameters, or undistort the "
                                 "images first (`colmap image_undistorter`, or `insertnerf poses` on the photos)")
        zoomed.append(d)
    return Cameras(K, cameras.c2w, cameras.height, cameras.width), zoomed


def assemble(views: ReadViews, background: tuple[float, float, float]) -> Scene:
    """Check the views and build the Scene: common size, bounds (format > points > geometry), layout."""
    if not views.paths:
        raise SceneError(f"{views.root}: the {views.format} scene lists no images")
    check_views(views)
    cameras, distortion = undistorted_cameras(views, unify_sizes(views))
    layout = views.layout or detect_layout(cameras)
    given = views.near is not None and views.far is not None
    if given:
        near, far = views.near.to(torch.float64), views.far.to(torch.float64)
    else:
        near, far = bounds_from_geometry(cameras, layout)
        if views.depths is not None:
            near, far = bounds_from_depths(views.depths, (near, far))
    _check_bounds(views, near, far, given)
    return Scene(root=views.root, cameras=cameras, image_paths=views.paths, near=near, far=far,
                 splits=views.splits, layout=layout, format=views.format, background=background,
                 depth_paths=views.depth_paths, depth_scale=views.depth_scale, distortion=distortion,
                 points=views.points)
