"""What a `render` or `eval` run is asked for and what it reports: the records that the pipelines fill and that
render_config.json, the eval JSON and the HTML pages are written from."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

from insertnerf_cli.config import DEFAULT_RESOLUTION, DEFAULT_VIEWS, config_to_json
from insertnerf_cli.exporters.report.html import duration
from insertnerf_cli.rendering.options import RenderOptions

DEFAULT_FRAMES = 30
DEFAULT_FPS = 15.0


@dataclass(frozen=True)
class RenderConfig:
    """Settings of one `render` run.

    Attributes:
        path: "orbit", "spiral", "input", or None to choose by the scene's layout (orbit for object-centric).
        path_file: a camera path file instead (nerfstudio camera_path.json or a transforms.json of target cameras;
            rendering/path_files.py): its cameras exactly, in the scene's units and axes.
        frames: frames of an orbit/spiral (None = DEFAULT_FRAMES); for "input", None = every input view.
        fps: frame rate of the videos (None: the path file's, else DEFAULT_FPS).
        resolution: long side of the frames in pixels (None = the images' size).
        views: reference views per frame.
        checkpoint: generator weights (None = the bundled pretrained ones).
        device: torch device name (cpu or cuda), resolved once by the command.
        chunk: rays per network call (bounds memory); None = DEFAULT_CHUNKS of the device.
        exact: every ray gets its own coarse pass and every pixel a fine pass (image_renderer.EXACT), instead of
            the default shortcuts (image_renderer.Shortcuts: within 0.3 dB, docs/benchmarks.md).
        sfm_depth: guide the fine samples by the scene's SfM points (depth_prior), triangulated at its poses first
            when it has none (triangulate.with_points).
        overwrite: replace the outputs of a different earlier run in the output folder.
        finetune_minutes: first fine-tune the weights on the scene for this long (cached as OUT/finetune.pt).
        depth_format: "png16" (uint16 PNGs, scale in cameras.json) or "npy" (float32 scene units, NaN invalid).
        pointcloud_points: write pointcloud.ply with at most this many points (None = no point cloud).
        points_cache: keep the SfM points triangulated at the scene's poses in this folder, shared by runs into
            other output folders (sfm/points_cache.py), instead of in OUT/points/.
        options: the render path's tuned numbers (RenderOptions), recorded in render_config.json and index.html.
        workers: processes that render frames side by side (pipelines/processes.py; the same picture with any
            number, up to float rounding); None: on a CPU one per core, each with a few frames; on a GPU one.
    """

    path: str | None = None
    frames: int | None = None
    fps: float | None = None
    path_file: Path | None = None
    resolution: int | None = DEFAULT_RESOLUTION
    views: int = DEFAULT_VIEWS
    checkpoint: Path | None = None
    device: str = "cpu"
    chunk: int | None = None
    exact: bool = False
    sfm_depth: bool = True
    overwrite: bool = False
    finetune_minutes: float | None = None
    depth_format: str = "png16"
    pointcloud_points: int | None = None
    points_cache: Path | None = None
    options: RenderOptions = field(default_factory=RenderOptions)
    workers: int | None = None


@dataclass(frozen=True)
class RenderSummary:
    """What `render` produced: ``rendered`` frames this run plus ``resumed`` kept from an interrupted one."""

    out_dir: Path
    path: str
    frames: int
    rendered: int
    resumed: int
    height: int
    width: int
    seconds_per_frame: float | None
    depth_clipped: int  # 0 by construction (outputs.depth_scale_for); counted so that a bug would show
    wall_s: float = 0.0  # the whole command, start-up and videos included
    resolution_asked: int | None = None  # a --resolution above the photos' size (frames never upsample)
    depth_scale: float | None = None  # depth_unit_scale_factor of the depth PNGs (None for npy)
    pointcloud_points: int | None = None  # points written to pointcloud.ply (None: not asked for)
    workers: int = 1  # processes that rendered frames side by side (pipelines/processes.py)

    def line(self) -> str:
        speed = "" if self.seconds_per_frame is None else f", {self.seconds_per_frame:.2f} s/frame"
        kept = f" ({self.resumed} kept from the earlier run)" if self.resumed else ""
        files = "video.mp4, depth.mp4, cameras.json, index.html"
        if self.pointcloud_points is not None:
            files += f", pointcloud.ply ({self.pointcloud_points} points)"
        notes = ""
        if self.depth_scale is not None:
            notes += f"; depth PNGs in steps of {self.depth_scale:g} units"
        if self.depth_clipped:
            notes += f"; {self.depth_clipped} depth pixels were clipped (a bug: please report it)"
        if self.resolution_asked:
            notes += f"; --resolution {self.resolution_asked} is above the photos' size, which was kept (no upsampling)"
        return (f"{self.frames} frames ({self.path}, {self.width}x{self.height}) in {self.out_dir.resolve()}: "
                f"rendered {self.rendered}{kept}{speed}, {duration(self.wall_s)} in total; see {files}{notes}")


@dataclass(frozen=True)
class EvalConfig:
    """Settings of one `eval` run (resolution, checkpoint, device, chunk, exact, sfm_depth as in RenderConfig).

    Attributes:
        views: reference views per held-out view, or a tuple of counts to score each of (same held-out views).
        out_dir: folder for side-by-side images (render | truth | error) and report.html, or None for none.
        json_path: file for the report (keys psnr, ssim, views; for several counts: by_count), or None.
        max_views: score at most this many held-out views, evenly spread (None = all); the others stay out of the
            references, so each score is the one the full run gives that view.
        overwrite: replace an existing JSON report and side-by-side images.
        points_cache: keep the SfM points triangulated at the scene's poses in this folder (as RenderConfig), else
            in out_dir/points/ where there is an out_dir.
        options: the render path's tuned numbers (RenderOptions), recorded in the JSON report and report.html.
        workers: processes that score held-out views side by side (as RenderConfig.workers).
    """

    views: int | tuple[int, ...] = DEFAULT_VIEWS
    resolution: int | None = DEFAULT_RESOLUTION
    checkpoint: Path | None = None
    device: str = "cpu"
    chunk: int | None = None
    exact: bool = False
    sfm_depth: bool = True
    out_dir: Path | None = None
    json_path: Path | None = None
    max_views: int | None = None
    overwrite: bool = False
    points_cache: Path | None = None
    options: RenderOptions = field(default_factory=RenderOptions)
    workers: int | None = None

    @property
    def counts(self) -> tuple[int, ...]:
        """The reference-view counts to score, ascending, each once."""
        counts = (self.views,) if isinstance(self.views, int) else tuple(self.views)
        if not counts or min(counts) < 1:
            raise ValueError(f"reference-view counts must be >= 1, got {self.views!r}")
        return tuple(sorted(set(counts)))


@dataclass(frozen=True)
class ViewScore:
    """One held-out view: its index and file name, scores, and the reference views it was rendered from."""

    index: int
    name: str
    psnr: float
    ssim: float
    references: tuple[int, ...]
    seconds: float


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


@dataclass(frozen=True)
class EvalReport:
    """Mean PSNR (dB) and SSIM over the held-out views at one reference-view count, and each view's record."""

    scene: Path
    height: int
    width: int
    psnr: float
    ssim: float
    views: tuple[ViewScore, ...]
    reference_views: int = DEFAULT_VIEWS

    def to_json(self) -> dict:
        """JSON-ready dict with keys psnr, ssim, views (infinite PSNR of a perfect view is written as null)."""
        views = [{**asdict(v), "psnr": _finite(v.psnr), "references": list(v.references)} for v in self.views]
        return {"psnr": _finite(self.psnr), "ssim": self.ssim, "views": views, "scene": str(self.scene),
                "height": self.height, "width": self.width, "reference_views": self.reference_views}


@dataclass(frozen=True)
class EvalRun:
    """One `eval` run: a report per reference-view count (ascending), its settings and wall time."""

    config: EvalConfig
    checkpoint: Path
    reports: tuple[EvalReport, ...]
    wall_s: float

    def to_json(self) -> dict:
        """One count: the report's keys (psnr, ssim, views, ...). Several: reference_views (the counts) and
        by_count (one report each, ascending), with the scene and size. Both: the switches and options the
        views were rendered under."""
        options = {"exact": self.config.exact, "sfm_depth": self.config.sfm_depth,
                   "options": config_to_json(self.config.options)}
        if len(self.reports) == 1:
            return {**self.reports[0].to_json(), **options}
        first = self.reports[0]
        return {"scene": str(first.scene), "height": first.height, "width": first.width,
                "reference_views": [r.reference_views for r in self.reports],
                "by_count": [r.to_json() for r in self.reports], **options}
