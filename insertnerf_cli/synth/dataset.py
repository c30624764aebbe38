"""A dataset of synthetic scenes rendered in parallel, resumable, rebuildable from its manifest.

``OUT_DIR/manifest.json`` records the generator version, the options and the :class:`SceneSpec` of every
scene before anything is rendered. Each scene is rendered into a hidden temporary folder and renamed to
``scene_NNNNN`` only when complete, so a killed run leaves no folder that looks finished; running again with
the same options skips finished scenes, deletes leftover temporary folders and renders the rest. The manifest
and scene folders are recorded in ``OUT_DIR/.insertnerf-outputs.json`` before they are made, each scene's files
in the scene's own record, so --overwrite removes only what synth wrote (outdir.py).
"""
from __future__ import annotations

import json
import multiprocessing
import os
import shutil
import signal
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Iterable, Iterator, Literal

import cv2
import torch

from insertnerf_cli.errors import UserError
from insertnerf_cli.files.atomic import write_error, write_json
from insertnerf_cli.files.lock import lock_output, releases_output_locks
from insertnerf_cli.files.outdir import OutputRecord, check_output, foreign_entries, move_into, record_tree
from insertnerf_cli.synth.capture import CaptureOptions
from insertnerf_cli.synth.layouts import FOV_RANGE
from insertnerf_cli.synth.scene import LAYOUTS, RenderedScene, SceneSpec, draw_layout, defaults_left_out, render_scene

# Bump when a change makes the same seed and options give other pixels.
GENERATOR_VERSION = "synth-5"
MANIFEST = "manifest.json"
SCENE_FILE = "scene.json"  # written last into a scene's temporary folder: a scene folder with it is finished
_TEMP_PREFIX = ".tmp-"
_OWNER = "synth"  # the name of its list in an output record (outdir.py)
LayoutChoice = Literal["object", "forward", "360", "handheld", "mixed"]
# What datasets of versions without output records hold (the only names --overwrite removes there).
_LEGACY_SCENE_DIRS = "scene_[0-9]*/"
_LEGACY_SCENE_FILES = ("*/r_[0-9]*.png", "depth/*/r_[0-9]*.png", "transforms_*.json", SCENE_FILE, "depth/*/",
                       "*/")


@dataclass(frozen=True)
class SynthOptions:
    """What a dataset is made of (recorded in the manifest).

    Attributes:
        scenes: number of scenes.
        views: views per scene, of which ``test_views`` are held out (transforms_test.json).
        resolution: long side of the images, pixels; the short side follows the drawn aspect ratio.
        layout: "object", "forward", "360", "handheld", or "mixed" (each scene draws one of the four).
        seed: dataset seed (>= 0); scene i uses the streams of (seed, i).
        aspects: aspect ratios (long / short) drawn per scene; (1.0,) gives square images.
        capture: sensor noise, exposure/white-balance jitter, JPEG compression (all off by default).
        fov: (lowest, highest) field of view of the long side, degrees, drawn uniformly per scene.
        supports: the 360 layout's subjects stand on a support (a plinth, a pedestal or a table) instead of the
            floor: the captures walked round an object on a stand that the generator finds hardest.
    """

    scenes: int = 10
    views: int = 50
    test_views: int = 8
    resolution: int = 200
    layout: LayoutChoice = "mixed"
    seed: int = 0
    aspects: tuple[float, ...] = (1.0, 4 / 3, 3 / 2, 16 / 9)
    capture: CaptureOptions = field(default_factory=CaptureOptions)
    fov: tuple[float, float] = FOV_RANGE
    supports: bool = False

    def __post_init__(self) -> None:
        if self.scenes < 1 or self.views < 1:
            raise UserError(f"need at least 1 scene and 1 view, got {self.scenes} scenes of {self.views} views")
        if not 0 <= self.test_views < self.views:
            raise UserError(f"--test-views must be between 0 and views - 1 ({self.views - 1}), got {self.test_views}")
        if self.resolution < 8:
            raise UserError(f"--resolution must be at least 8 pixels, got {self.resolution}")
        if self.layout not in (*LAYOUTS, "mixed"):
            raise UserError(f"unknown layout {self.layout!r}; use one of {', '.join(LAYOUTS)} or mixed")
        if self.seed < 0:
            raise UserError(f"--seed must be >= 0, got {self.seed}")
        if not self.aspects or min(self.aspects) < 1.0:
            raise UserError(f"aspect ratios are long/short side and must be >= 1, got {self.aspects}")
        low, high = self.fov
        if not 1.0 <= low <= high <= 170.0:
            raise UserError(f"--fov takes LOW:HIGH degrees with 1 <= LOW <= HIGH <= 170, got {low:g}:{high:g}")

    def to_json(self) -> dict:
        return defaults_left_out({**asdict(self), "aspects": list(self.aspects)}, self.fov, self.supports)

    def spec(self, index: int) -> SceneSpec:
        """The spec of scene ``index``."""
        layout = draw_layout(self.seed, index) if self.layout == "mixed" else self.layout
        return SceneSpec(index=index, seed=self.seed, layout=layout, views=self.views, test_views=self.test_views,
                         resolution=self.resolution, aspects=tuple(self.aspects), capture=self.capture,
                         fov=tuple(self.fov), supports=self.supports)


@dataclass(frozen=True)
class Manifest:
    """What ``manifest.json`` holds: enough to rebuild every scene exactly (render_scene(spec) per scene)."""

    version: str
    options: SynthOptions
    scenes: tuple[SceneSpec, ...]

    def to_json(self) -> dict:
        return {"generator": "insertnerf synth", "version": self.version, "options": self.options.to_json(),
                "scenes": [s.to_json() for s in self.scenes]}


@dataclass(frozen=True)
class DatasetRun:
    """The outcome of one run: the manifest, scenes rendered now and found finished, and views per second."""

    manifest: Manifest
    rendered: int
    skipped: int
    views_per_second: float


def generate_dataset(out_dir: str | os.PathLike, options: SynthOptions, workers: int = 1) -> Manifest:
    """Render every scene of ``options`` under ``out_dir`` that is not there yet; see :func:`build_dataset`."""
    return build_dataset(out_dir, options, workers).manifest


@releases_output_locks
def build_dataset(out_dir: str | os.PathLike, options: SynthOptions, workers: int = 1, overwrite: bool = False,
                  progress: bool = True) -> DatasetRun:
    """Render every scene of ``options`` under ``out_dir`` that is not there yet.

    Args:
        out_dir: the dataset folder (created).
        options: what to render.
        workers: parallel worker processes (1 renders in this process).
        overwrite: delete the scenes and manifest of a dataset with other options instead of refusing.
        progress: show a progress bar on stderr.
    Raises:
        UserError: out_dir holds something else (another dataset, other files) and overwrite is False.
    """
    out = Path(out_dir)
    manifest = Manifest(GENERATOR_VERSION, options, tuple(options.spec(i) for i in range(options.scenes)))
    _prepare(out, manifest, overwrite)
    pending = [s for s in manifest.scenes if not (out / s.name / SCENE_FILE).is_file()]
    start = time.perf_counter()
    views = sum(result.views for result in _run(out, pending, workers, progress, total=len(manifest.scenes)))
    elapsed = time.perf_counter() - start
    return DatasetRun(manifest, len(pending), len(manifest.scenes) - len(pending),
                      views / elapsed if views else 0.0)


def _prepare(out: Path, manifest: Manifest, overwrite: bool) -> None:
    """Create ``out`` or check it holds this very dataset; remove leftovers of interrupted runs."""
    check_output(out, [], what="the output folder")
    lock_output(out, _OWNER)
    out.mkdir(parents=True, exist_ok=True)
    path = out / MANIFEST
    ours = manifest.to_json()
    if path.is_file():
        try:
            theirs = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError):
            theirs = None
        if theirs != ours:
            if not overwrite:
                raise UserError(f"{out} holds a dataset made with other options or another generator version; "
                                f"choose another folder, or pass --overwrite to replace it")
            _remove_dataset(out)
    elif any(p for p in foreign_entries(out, _OWNER) if not p.startswith(_TEMP_PREFIX)):
        if not overwrite:
            raise UserError(f"{out} is not empty and has no {MANIFEST}; choose an empty or new folder, "
                            f"or pass --overwrite to write into it (its other files are kept)")
        _remove_dataset(out)
    _remove_temporaries(out, manifest.scenes)  # scenes a killed run did not finish
    OutputRecord(out, _OWNER).claim(MANIFEST, *(spec.name for spec in manifest.scenes))
    write_json(path, ours)


def _remove_dataset(out: Path) -> None:
    """Delete what synth wrote in ``out`` (manifest, scene folders and their files) and nothing else."""
    record = OutputRecord(out, _OWNER)
    if not record.exists:  # a dataset of a version without records: its scene folders by their file names
        for scene in out.glob(_LEGACY_SCENE_DIRS.rstrip("/")):
            if scene.is_dir() and not scene.is_symlink():
                OutputRecord(scene, _OWNER).remove(legacy=_LEGACY_SCENE_FILES)
    record.remove(legacy=(MANIFEST, _LEGACY_SCENE_DIRS))


def render_into(out: Path, spec: SceneSpec) -> RenderedScene:
    """Render one scene into a temporary folder and rename it into place only when it is complete."""
    temp = out / f"{_TEMP_PREFIX}{spec.name}-{os.getpid()}"
    shutil.rmtree(temp, ignore_errors=True)
    try:
        try:
            result = render_scene(spec, temp)
        except OSError as err:  # disk full, no permission: not a generator bug
            raise write_error(out / spec.name, err) from None
        except Exception as err:  # a generator bug: name the scene so it can be rebuilt and reported
            raise UserError(f"synth: {spec.name} (seed {spec.seed}, layout {spec.layout}) failed with "
                            f"{type(err).__name__}: {err}. This is a generator bug; please report it with the "
                            f"dataset's manifest.json (finished scenes are kept, re-running resumes).") from err
        record_tree(temp, _OWNER)
        move_into(temp, out / spec.name, _OWNER)  # a plain rename unless a user's file kept the old folder
        return result
    finally:
        shutil.rmtree(temp, ignore_errors=True)


def _worker(job: tuple[Path, SceneSpec]) -> RenderedScene:
    return render_into(*job)


def _init_worker() -> None:
    """One thread per worker process: the workers are the parallelism, and oversubscribed torch threads
    slowed ray generation 50-fold on a busy 2-core machine. Ctrl-C is the parent's to handle: a terminal sends
    it to every worker too, and a worker that raised KeyboardInterrupt before the parent's pool terminated it
    printed a traceback (bench/hostile.py, synth_ctrl_c_during_work, under load). The pool ends its workers with
    SIGTERM, after every run and on Ctrl-C: a forked worker inherits the failure handler that pycolmap's logging
    installs when the parent imports it (with the other commands), and that handler printed a C++ stack trace
    for each worker, so SIGTERM gets its default action back."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    torch.set_num_threads(1)
    cv2.setNumThreads(1)


@contextmanager
def _single_threaded() -> Iterator[None]:
    """Torch and OpenCV on one thread while rendering in this process (restored afterwards)."""
    before = torch.get_num_threads(), cv2.getNumThreads()
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before[0])
        cv2.setNumThreads(before[1])


def _run(out: Path, pending: list[SceneSpec], workers: int, progress: bool, total: int) -> Iterator[RenderedScene]:
    """Render ``pending`` scenes (in ``workers`` processes when > 1), with a progress bar."""
    from tqdm import tqdm

    bar = tqdm(total=total, initial=total - len(pending), unit="scene", desc="synth", disable=not progress,
               dynamic_ncols=True)
    start = time.perf_counter()
    try:
        if workers <= 1 or len(pending) <= 1:
            with _single_threaded():
                results: Iterator[RenderedScene] = (render_into(out, s) for s in pending)
                yield from _report(results, bar, start)
        else:
            context = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods()
                                                  else "spawn")
            try:
                # Forked while this process's OpenCV pool is down to one thread: a worker whose _init_worker
                # reconfigured a pool whose threads the fork left behind waited for them forever.
                with _single_threaded(), context.Pool(min(workers, len(pending)), initializer=_init_worker) as pool:
                    yield from _report(pool.imap_unordered(_worker, [(out, s) for s in pending]), bar, start)
            finally:  # the pool has terminated and joined its workers: the scenes they left half-done
                _remove_temporaries(out, pending)
    finally:
        bar.close()


def _remove_temporaries(out: Path, specs: Iterable[SceneSpec]) -> None:
    """Delete the temporary folders of these scenes (render_into's), whichever process made them."""
    for spec in specs:
        for leftover in out.glob(f"{_TEMP_PREFIX}{spec.name}-*"):
            if leftover.is_dir() and not leftover.is_symlink():
                shutil.rmtree(leftover, ignore_errors=True)


def _report(results: Iterator[RenderedScene], bar, start: float) -> Iterator[RenderedScene]:
    views = 0
    for result in results:
        views += result.views
        bar.set_postfix(views_per_s=f"{views / max(time.perf_counter() - start, 1e-9):.1f}")
        bar.update(1)
        yield result
