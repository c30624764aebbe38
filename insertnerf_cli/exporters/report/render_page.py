"""`render`'s index.html: the video and the depth video side by side, every frame in a strip, the settings and
timings, and the camera path among the input cameras from above and from the side."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.config import config_to_json
from insertnerf_cli.exporters.outputs import CAMERAS_JSON, depth_name, frame_name
from insertnerf_cli.exporters.records import RenderConfig, RenderSummary
from insertnerf_cli.exporters.report.html import duration, esc, link, options_table, page, settings_table, table
from insertnerf_cli.exporters.report.svg import ViewAxes, cameras_views


@dataclass(frozen=True)
class RenderPage:
    """What the page shows: the run's summary and settings, the scene folder, the rendered path's cameras and
    the input cameras (both in the scene's units) with the inputs' image names."""

    summary: RenderSummary
    config: RenderConfig
    scene_dir: Path
    path: Cameras
    inputs: Cameras
    input_names: tuple[str, ...]


def _settings(p: RenderPage) -> list[tuple[str, object]]:
    s, c = p.summary, p.config
    depth = (f"uint16 PNG, depth = value x {s.depth_scale:g} (cameras.json depth_unit_scale_factor)"
             if s.depth_scale is not None else "float32 .npy in the scene's units, NaN = invalid")
    items = [("scene", p.scene_dir.resolve()), ("input views", len(p.inputs)), ("camera path", s.path),
             ("frames", s.frames), ("size", f"{s.width} x {s.height} px"), ("reference views per frame", c.views),
             ("weights", c.checkpoint.name if c.checkpoint is not None else "bundled default (fast)"),
             ("shortcuts", "off (--exact)" if c.exact else "on"), ("device", c.device), ("fps", f"{c.fps:g}"),
             ("depth files", depth)]
    if c.finetune_minutes is not None:
        items.append(("fine-tuned first", f"{c.finetune_minutes:g} min"))
    return items


def _timings(s: RenderSummary) -> list[tuple[str, object]]:
    speed = "-" if s.seconds_per_frame is None else f"{s.seconds_per_frame:.2f} s"
    return [("frames rendered by this run", s.rendered), ("frames kept from an earlier run", s.resumed),
            ("seconds per rendered frame", speed), ("processes rendering frames", s.workers),
            ("whole command", duration(s.wall_s))]


def _strip(p: RenderPage) -> str:
    fmt = "npy" if p.summary.depth_scale is None else "png16"
    figures = []
    for i in range(p.summary.frames):
        name = frame_name(i)
        figures.append(f'<figure><a href="{link("frames/" + name)}"><img loading="lazy" alt="frame {i}" '
                       f'src="{link("frames/" + name)}"></a><a href="{link("depth_vis/" + name)}"><img '
                       f'loading="lazy" alt="depth {i}" src="{link("depth_vis/" + name)}"></a><figcaption>'
                       f'{i:05d} &middot; <a href="{link("depth/" + depth_name(i, fmt))}">depth</a></figcaption>'
                       "</figure>")
    return f'<div class="strip">{"".join(figures)}</div>'


def _camera_drawing(p: RenderPage) -> str:
    def arrays(cams: Cameras) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c2w = cams.c2w.double().cpu().numpy()
        return c2w[:, :3, 3], c2w[:, :3, 2], -c2w[:, :3, 1]  # centres, optical axes, up (OpenCV: -y)

    (ic, iforward, iup), (pc, pforward, _) = arrays(p.inputs), arrays(p.path)
    # Orbits and spirals loop (paths.py): the video goes from the last frame back to the first.
    return cameras_views(pc, pforward, ic, iforward, ViewAxes.of(ic, iup), closed=p.summary.path != "input")


def render_page(p: RenderPage) -> str:
    """The whole index.html."""
    s = p.summary
    videos = ('<div class="pair">'
              f'<figure><video src="video.mp4" poster="{link("frames/" + frame_name(0))}" controls loop muted '
              'autoplay playsinline></video><figcaption>video.mp4</figcaption></figure>'
              f'<figure><video src="depth.mp4" poster="{link("depth_vis/" + frame_name(0))}" controls loop muted '
              'autoplay playsinline></video><figcaption>depth.mp4 (turbo: red near, blue far, black '
              'invalid)</figcaption></figure></div>')
    files = [(f'<a href="{link(name)}">{esc(name)}</a>', esc(what)) for name, what in
             (("video.mp4", "the frames as H.264"), ("depth.mp4", "the depth maps as H.264"),
              (CAMERAS_JSON, "nerfstudio transforms of the path, with the depth scale"),
              ("render_config.json", "the settings the frames depend on"))]
    if s.pointcloud_points is not None:
        files.append((f'<a href="{link("pointcloud.ply")}">pointcloud.ply</a>',
                      esc(f"{s.pointcloud_points} coloured points in the scene's units")))
    body = (f"<h2>Videos</h2>{videos}<h2>Frames</h2>{_strip(p)}"
            f'<h2>Camera path</h2><div class="drawings">{_camera_drawing(p)}</div><p class="sub">Blue: the {s.frames} '
            f"rendered frames (ringed: the first); grey: the {len(p.inputs)} input cameras; ticks along the optical "
            "axes.</p>"
            f"<h2>Settings</h2>{settings_table(_settings(p))}<h2>Timings</h2>{settings_table(_timings(s))}"
            f"<h2>Render options</h2>{options_table(config_to_json(p.config.options))}"
            f"<h2>Files</h2>{table(('file', 'content'), files)}")
    return page(f"insertnerf render: {p.scene_dir.resolve().name}",
                f"{s.frames} frames, {s.path} path, {s.width} x {s.height} px", body)
