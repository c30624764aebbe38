"""Camera poses from a folder of images with pycolmap, in process, on CPU. The pycolmap calls that build a model
live in this file, those that read one (and the database) in reconstruction.py; the API differences between pycolmap
versions are absorbed by :func:`insertnerf_cli.poses.reconstruction.cam_from_world`.

Pipeline (``estimate_poses``): read and check the images -> SIFT features -> matching (exhaustive for small sets,
sequential for long ones) -> incremental mapping, keeping the model with the most registered images -> when the
model tears the capture's name order (a folded walk, :func:`insertnerf_cli.poses.check.torn_links`), mapping again
from each image's neighbours in name order alone -> a check of the poses against independent two-view estimates
(:mod:`insertnerf_cli.poses.check`) -> undistortion to PINHOLE ->
``transforms.json``, the COLMAP model, ``sparse.ply`` and ``cameras.ply``. Everything is written into a temporary
folder beside the output and renamed into place at the end, so a failure never leaves half a scene.
"""
from __future__ import annotations

import os
import shutil
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Literal

import pycolmap
import torch

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.errors import UserError
from insertnerf_cli.files.lock import lock_output, releases_output_locks
from insertnerf_cli.poses.check import CheckLimits, PoseCheck, check_relative_poses
from insertnerf_cli.poses.child import run_in_child
from insertnerf_cli.poses.extraction import extract_sift
from insertnerf_cli.poses.folder import OWNER, InputImages, check_output, read_inputs, staging_folder, write_scene
from insertnerf_cli.poses.matching import match
from insertnerf_cli.poses.reconstruction import (
    features_only,
    model_arrays,
    pair_matches,
    scaled_limits,
    torn_neighbours,
    undistort,
)
from insertnerf_cli.poses.stages import Report, StageTime, Stages, num_threads, pycolmap_log

Matcher = Literal["auto", "exhaustive", "sequential", "chain"]

# Under this fraction of registered images the result is probably not what the user wanted (nerfstudio's habit).
WARN_REGISTERED_FRACTION = 0.8
MIN_REGISTERED = 3
# COLMAP's first image pair must see its points under 16 degrees or more; photos of a hand-held forward-facing
# capture (0.6-3 degrees apart) have no such pair, and COLMAP's own relaxation does not reach them, while 4 degrees
# registers them all (measured: docs/research-log.md, Poses and triangulation).
DEFAULT_INIT_TRI_ANGLE = pycolmap.IncrementalPipelineOptions().mapper.init_min_tri_angle
RELAXED_INIT_TRI_ANGLE = 4.0


@dataclass(frozen=True)
class PosesOptions:
    """How ``estimate_poses`` runs.

    Attributes:
        matcher: "exhaustive" (every pair), "sequential" (neighbours in name order, for video frames, with links
            2, 4, 8, ... images ahead), "chain" (only the ``chain_overlap`` next images in name order) or "auto"
            (exhaustive up to ``exhaustive_limit`` images, sequential above, see ``exhaustive_fallback_limit``;
            either one mapped again as a chain when its model tears the name order).
        max_image_size: long side, pixels, that SIFT sees (CPU SIFT memory grows with the image size).
        camera_model: COLMAP camera model fitted before undistortion (SIMPLE_RADIAL, RADIAL, OPENCV, PINHOLE).
        num_threads: CPU threads; 0 = every core this process may use.
        overwrite: replace an existing output folder.
        verbose: let pycolmap print its own log.
        check: limits of the two-view consistency check (:mod:`insertnerf_cli.poses.check`).
        allow_inconsistent: only warn when the pose check fails (else it is an error).
        check_pairs: at most this many image pairs are compared by the check (general pairs first).
        exhaustive_limit: the "auto" matcher's switch point.
        exhaustive_fallback_limit: up to this many images, "auto" matches every pair after all when the
            sequential matcher places under WARN_REGISTERED_FRACTION of them (photos not in video order).
        sequential_overlap: neighbours matched to each image by the sequential matcher.
        chain_overlap: images after each one that the chain matcher matches it with.
        init_tri_angle: degrees between the rays of the first pair's points that mapping starts from (None: COLMAP's
            own, DEFAULT_INIT_TRI_ANGLE); a mapping that places too few images is run again at
            RELAXED_INIT_TRI_ANGLE.
        seed: random seed of the mapper.
    """

    matcher: Matcher = "auto"
    max_image_size: int = 1600
    camera_model: str = "SIMPLE_RADIAL"
    num_threads: int = 0
    overwrite: bool = False
    verbose: bool = False
    check: CheckLimits = CheckLimits()
    allow_inconsistent: bool = False
    check_pairs: int = 300
    exhaustive_limit: int = 100
    exhaustive_fallback_limit: int = 300
    sequential_overlap: int = 10
    chain_overlap: int = 5
    init_tri_angle: float | None = None
    seed: int = 0


@dataclass(frozen=True)
class PosesResult:
    """What ``estimate_poses`` produced.

    Attributes:
        scene_dir: the output folder.
        registered: names of the N registered images, in camera order (sorted by name).
        unregistered: names of the input images COLMAP could not place.
        cameras: N undistorted PINHOLE cameras, OpenCV c2w, in COLMAP's world (arbitrary scale).
        near, far: [N] per-view bounds from the depths of the points each image sees.
        num_points: sparse points in the model.
        mean_reprojection_error: pixels.
        check: agreement with independent two-view estimates.
        matcher: the matcher that ran.
        stages: wall time per stage.
    """

    scene_dir: Path
    registered: tuple[str, ...]
    unregistered: tuple[str, ...]
    cameras: Cameras
    near: torch.Tensor  # [N]
    far: torch.Tensor  # [N]
    num_points: int
    mean_reprojection_error: float
    check: PoseCheck
    matcher: str
    stages: tuple[StageTime, ...]

    @property
    def registered_fraction(self) -> float:
        return len(self.registered) / (len(self.registered) + len(self.unregistered))

    def summary(self) -> str:
        total = len(self.registered) + len(self.unregistered)
        return (f"{len(self.registered)}/{total} images registered, {self.num_points} points, mean reprojection "
                f"error {self.mean_reprojection_error:.2f} px, {sum(t.seconds for t in self.stages):.0f} s in total; "
                f"scene written to {Path(self.scene_dir).resolve()}")


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


@releases_output_locks
def estimate_poses(images_dir: str | os.PathLike, out_dir: str | os.PathLike,
                   options: PosesOptions = PosesOptions(), report: Report = _stderr) -> PosesResult:
    """Estimate camera poses of the images in ``images_dir`` and write a posed scene folder to ``out_dir``.

    Writes ``images/`` (undistorted), ``transforms.json`` (nerfstudio / instant-ngp: OpenGL c2w, relative paths,
    per-frame ``near``/``far``), ``colmap/sparse/0`` (the undistorted PINHOLE model), ``colmap/database.db``,
    ``sparse.ply`` and ``cameras.ply``. Progress lines go to ``report``.

    Raises:
        UserError: fewer than 3 images, unreadable or mixed-size images, an existing output without overwrite,
            no model, fewer than 3 registered images, or poses that contradict the two-view check.
    """
    images_dir, out_dir = Path(images_dir), Path(out_dir)
    check_output(images_dir, out_dir, options.overwrite)
    lock_output(out_dir, OWNER, is_dir=False)  # beside the folder: a killed run leaves no folder that is not a scene
    stages = Stages(report, total=6)
    stages.start("reading images", str(images_dir))
    with staging_folder(out_dir) as tmp, pycolmap_log(options.verbose):
        inputs = read_inputs(images_dir, tmp / "colmap" / "input")
        stages.done(f"{len(inputs.names)} images of {inputs.width}x{inputs.height}")
        work = tmp / "colmap"
        matcher = _run_features_and_matching(inputs, work / "database.db", options, stages)
        rec, model_dir, matcher = _map_or_match_every_pair(inputs, work, options, matcher, stages)
        rec, model_dir, matcher = _map_a_torn_walk_as_a_chain(inputs, work, options, matcher, rec, model_dir, stages)
        check = _run_check(rec, work / "database.db", inputs, options, stages)
        stages.start("writing the scene", "undistorting to PINHOLE")
        undistorted = undistort(model_dir, inputs.folder, tmp)
        shutil.rmtree(work / "mapping")
        shutil.rmtree(work / "input", ignore_errors=True)  # copies made for COLMAP, now in images/ undistorted
        scene = write_scene(tmp, model_arrays(undistorted))
        stages.done(f"{len(scene.names)} images, transforms.json, sparse.ply, cameras.ply")
    registered = set(scene.names)
    result = PosesResult(out_dir, tuple(scene.names), tuple(inputs.original(n) for n in inputs.names
                                                            if n not in registered),
                         scene.cameras, scene.near, scene.far, scene.num_points,
                         float(rec.compute_mean_reprojection_error()), check, matcher, tuple(stages.times))
    _report_result(result, report)
    return result


def _report_result(result: PosesResult, report: Report) -> None:
    if result.unregistered:
        shown = ", ".join(result.unregistered[:10]) + (" ..." if len(result.unregistered) > 10 else "")
        report(f"not registered ({len(result.unregistered)}): {shown}")
    if result.registered_fraction < WARN_REGISTERED_FRACTION:
        report(f"warning: only {100 * result.registered_fraction:.0f} % of the images were registered; blur, "
               "little overlap between views or textureless surfaces are the usual causes.")


def _run_features_and_matching(inputs: InputImages, db_path: Path, options: PosesOptions,
                               stages: Stages) -> str:
    """SIFT features and matches into ``db_path``; returns the matcher used."""
    _extract(inputs, db_path, options, num_threads(options.num_threads), stages)
    matcher = options.matcher
    if matcher == "auto":
        matcher = "exhaustive" if len(inputs.names) <= options.exhaustive_limit else "sequential"
    _match(db_path, matcher, len(inputs.names), options, stages)
    return matcher


def _match(db_path: Path, matcher: str, images: int, options: PosesOptions, stages: Stages) -> None:
    """One matching stage: COLMAP's matcher with progress, then how many pairs the mapper can use."""
    overlap = options.chain_overlap if matcher == "chain" else options.sequential_overlap
    stages.done(match(db_path, matcher, images, overlap, num_threads(options.num_threads),
                      lambda what: stages.start("matching", what),
                      lambda done, pairs: stages.tick(done, pairs, "image pairs matched")))


def _map_or_match_every_pair(inputs: InputImages, work: Path, options: PosesOptions, matcher: str,
                             stages: Stages) -> tuple["pycolmap.Reconstruction", Path, str]:
    """Mapping, and the matcher behind the model. When "auto" chose the sequential matcher (more than
    ``exhaustive_limit`` images) and it places under WARN_REGISTERED_FRACTION of them, the photos are not in video
    order: up to ``exhaustive_fallback_limit`` images, every pair is matched (the sequential pairs are kept) and
    mapping runs again."""
    n = len(inputs.names)
    fallback = options.matcher == "auto" and matcher == "sequential" and n <= options.exhaustive_fallback_limit
    try:
        rec, model_dir = _run_mapping(inputs, work, options, stages)
    except UserError:
        if not fallback:
            raise
        placed = f"fewer than {MIN_REGISTERED}"
    else:
        if not fallback or rec.num_reg_images() >= WARN_REGISTERED_FRACTION * n:
            return rec, model_dir, matcher
        placed = str(rec.num_reg_images())
    stages.total += 2
    stages.report(f"      sequential matching placed {placed} of {n} images: the photos are not in video order; "
                  "matching every pair and mapping again")
    shutil.rmtree(work / "mapping")
    _match(work / "database.db", "exhaustive", n, options, stages)
    rec, model_dir = _run_mapping(inputs, work, options, stages)
    return rec, model_dir, "exhaustive"


def _map_a_torn_walk_as_a_chain(inputs: InputImages, work: Path, options: PosesOptions, matcher: str,
                                rec: "pycolmap.Reconstruction", model_dir: Path,
                                stages: Stages) -> tuple["pycolmap.Reconstruction", Path, str]:
    """The model, or one mapped from chain matches when the model tears the name order (check.torn_links) and
    the chain model tears it less, registering as many images. Asked for "exhaustive" or "chain", only a warning.

    Two chains are tried, each image with its next ``chain_overlap`` and then half as many: the mapper can break a
    chain (measured on bench/poses_fold.py, 20 views 18 degrees apart: 1 run in 6 registered 13 of them), and views
    farther apart along the walk can themselves look alike."""
    torn = _torn(rec, work / "database.db", inputs, options)
    where = ", ".join(f"{a} | {b}" for a, b in torn[:4]) + (" ..." if len(torn) > 4 else "")
    what = (f"the poses jump between {len(torn)} pair(s) of images that follow each other in name order and match "
            f"well ({where}): a symmetric object or repeated texture folded the walk")
    if not torn or options.matcher in ("exhaustive", "chain"):
        if torn:
            stages.report(f"      warning: {what}" + ("; try --matcher chain." if matcher != "chain" else "."))
        return rec, model_dir, matcher
    stages.report(f"      {what}; mapping again from neighbours in name order only")
    for attempt, overlap in enumerate(dict.fromkeys((options.chain_overlap, max(options.chain_overlap // 2, 1)))):
        chain = work / f"chain{attempt}"
        chain.mkdir()
        features_only(work / "database.db", chain / "database.db")
        stages.total += 2
        _match(chain / "database.db", "chain", len(inputs.names), replace(options, chain_overlap=overlap), stages)
        try:
            rec2, model_dir2 = _run_mapping(inputs, chain, replace(options, seed=options.seed + attempt), stages)
        except UserError as err:
            stages.report(f"      the chain did not map ({err})")
        else:
            torn2 = _torn(rec2, chain / "database.db", inputs, options)
            if len(torn2) < len(torn) and rec2.num_reg_images() >= rec.num_reg_images():
                stages.report(f"      the chain model keeps the walk ({len(torn2)} torn link(s)): using it")
                os.replace(chain / "database.db", work / "database.db")
                shutil.rmtree(work / "mapping")
                os.replace(chain / "mapping", work / "mapping")
                shutil.rmtree(chain)
                return rec2, work / "mapping" / model_dir2.name, "chain"
            stages.report(f"      the chain model tears {len(torn2)} link(s) and registers {rec2.num_reg_images()} "
                          "images")
        shutil.rmtree(chain)
    stages.report(f"      keeping the first model; warning: {what}")
    return rec, model_dir, matcher


def _extract(inputs: InputImages, db_path: Path, options: PosesOptions, threads: int, stages: Stages) -> None:
    """SIFT on every image; refuse images COLMAP's own decoder could not read (it skips them silently)."""
    stages.start("extracting SIFT features", f"{len(inputs.names)} images, long side capped at "
                 f"{options.max_image_size} px, {threads} threads")
    extraction = pycolmap.FeatureExtractionOptions(max_image_size=options.max_image_size, num_threads=threads)
    unread, keypoints = extract_sift(db_path, inputs.folder, inputs.names, pycolmap.CameraMode.SINGLE, extraction,
                                     pycolmap.ImageReaderOptions(camera_model=options.camera_model))
    stages.done(f"{keypoints} keypoints in {len(inputs.names) - len(unread)} images")
    missing = [inputs.original(name) for name in unread]
    if missing:
        raise UserError(f"COLMAP could not decode {len(missing)} image(s): {', '.join(missing[:10])}"
                        f"{' ...' if len(missing) > 10 else ''}; convert them to JPEG or PNG.")


def _run_mapping(inputs: InputImages, work: Path, options: PosesOptions,
                 stages: Stages) -> tuple["pycolmap.Reconstruction", Path]:
    """Incremental mapping; the model with the most registered images and its folder. When it places under
    WARN_REGISTERED_FRACTION of the images (or none), once more from an initial pair that may see its points under
    RELAXED_INIT_TRI_ANGLE, keeping the model that registers more."""
    n = len(inputs.names)
    stages.start("mapping", f"incremental, {n} images")
    rec, folder, others = _incremental(inputs, work / "mapping", options, options.init_tri_angle, stages)
    if rec is None or rec.num_reg_images() < WARN_REGISTERED_FRACTION * n:
        placed = "no model" if rec is None else f"{rec.num_reg_images()} of {n} images"
        first = options.init_tri_angle or DEFAULT_INIT_TRI_ANGLE
        stages.report(f"      {placed}: mapping again from a first pair of photos that see their points "
                      f"{RELAXED_INIT_TRI_ANGLE:g} degrees apart or more instead of {first:g} (photos taken close "
                      "together, such as a hand-held forward-facing capture, have no wider pair)")
        rec2, folder2, others2 = _incremental(inputs, work / "mapping_relaxed", options, RELAXED_INIT_TRI_ANGLE,
                                              stages)
        if rec2 is not None and (rec is None or rec2.num_reg_images() > rec.num_reg_images()):
            shutil.rmtree(work / "mapping")
            os.replace(work / "mapping_relaxed", work / "mapping")
            rec, folder, others = rec2, work / "mapping" / folder2.name, others2
        else:
            shutil.rmtree(work / "mapping_relaxed")
    if rec is None:
        raise UserError(f"COLMAP could not build any model from the {n} images in {inputs.source}: they share too "
                        "few matching features; use overlapping, sharp, textured photos of one scene.")
    if rec.num_reg_images() < MIN_REGISTERED:
        raise UserError(f"only {rec.num_reg_images()} of {n} images could be registered (need at least "
                        f"{MIN_REGISTERED}); use more overlapping, sharp, textured photos of one scene.")
    dropped = f"; other models dropped (registered images): {others}" if others else ""
    stages.done(f"{rec.num_reg_images()}/{n} registered, {rec.num_points3D()} points, "
                f"{rec.compute_mean_reprojection_error():.2f} px{dropped}")
    return rec, folder


def _incremental(inputs: InputImages, out: Path, options: PosesOptions, init_tri_angle: float | None,
                 stages: Stages) -> tuple["pycolmap.Reconstruction | None", Path, list[int]]:
    """One incremental mapping into ``out``: (the largest model or None, its folder, the others' sizes)."""
    n, registered = len(inputs.names), [0]

    def on_image() -> None:
        registered[0] += 1
        stages.tick(min(registered[0], n), n, "images registered so far, in all models (the largest is kept)")

    mapping = pycolmap.IncrementalPipelineOptions(num_threads=num_threads(options.num_threads),
                                                  random_seed=options.seed, min_model_size=MIN_REGISTERED)
    if init_tri_angle is not None:
        mapping.mapper.init_min_tri_angle = init_tri_angle
    out.mkdir(parents=True, exist_ok=True)

    def mapping_run(send: Callable[[object], None]) -> dict[int, int]:  # in the child: {model: registered images}
        models = pycolmap.incremental_mapping(out.parent / "database.db", inputs.folder, out, options=mapping,
                                              next_image_callback=lambda: send("image"))
        for key, model in models.items():  # the parent reads the models from their folders
            (out / str(key)).mkdir(parents=True, exist_ok=True)
            model.write(out / str(key))
        return {key: model.num_reg_images() for key, model in models.items()}

    models = run_in_child(mapping_run, lambda message: on_image())
    if not models:  # pycolmap logs "Failed to create any sparse model" and returns {} without raising
        return None, out, []
    best = max(models, key=lambda k: models[k])
    others = sorted((count for k, count in models.items() if k != best), reverse=True)
    return pycolmap.Reconstruction(out / str(best)), out / str(best), others


def _torn(rec: "pycolmap.Reconstruction", db_path: Path, inputs: InputImages,
          options: PosesOptions) -> list[tuple[str, str]]:
    return torn_neighbours(rec, db_path, inputs.names, _check_limits(inputs, options))


def _check_limits(inputs: InputImages, options: PosesOptions) -> CheckLimits:
    return scaled_limits(options.check, max(inputs.height, inputs.width), options.max_image_size)


def _run_check(rec: "pycolmap.Reconstruction", db_path: Path, inputs: InputImages, options: PosesOptions,
               stages: Stages) -> PoseCheck:
    stages.start("checking poses", "does the model explain each pair's matches as well as a two-view estimate?")
    limits = _check_limits(inputs, options)
    check = check_relative_poses(pair_matches(db_path, rec, options.check_pairs), limits)
    stages.done(check.summary())
    if not check.passed:
        message = (f"the poses contradict the images' own two-view geometry ({check.summary()}; limits "
                   f"{100 * limits.max_contradicted_share:g} % and {limits.max_median_deg:g} deg): repeated "
                   "texture or symmetric scenes probably fooled the matching")
        if not options.allow_inconsistent:
            raise UserError(message + "; add photos that break the symmetry, or pass --allow-inconsistent to "
                            "keep these poses anyway.")
        stages.report(f"warning: {message}.")
    return check


