"""A render's frames: each rendered and written as its three files, on one process or on several side by side
(pipelines/processes.py; no click here)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from insertnerf_cli.exporters.outputs import depth_to_float, depth_to_turbo, depth_to_uint16, frame_paths, write_frame
from insertnerf_cli.rendering.camera_paths import CameraPath
from insertnerf_cli.rendering.view_renderer import ViewRenderer

# Below half opacity a pixel shows mostly background, so its depth says little: it is written as invalid.
MIN_DEPTH_OPACITY = 0.5


def excluded_views(path: CameraPath, frame: int) -> list[int]:
    """The input views frame ``frame`` may not be rendered from: for the "input" path, the photo it re-renders."""
    return [path.source_index[frame]] if path.source_index is not None else []


@dataclass(frozen=True)
class FrameWriter:
    """The frames of ``path`` as work for processes.run_side_by_side: item i renders frame i and writes its three
    files in ``out_dir`` (outputs.frame_paths), depth in the scene's units (``similarity_scale``: normalised units
    per scene unit), stored as ``depth_format`` with ``depth_scale``, and a turbo picture of it between the path's
    nearest and farthest bounds."""

    path: CameraPath
    out_dir: Path
    similarity_scale: float
    depth_scale: float
    depth_format: str

    def run(self, renderer: ViewRenderer, index: int) -> int:
        """Render frame ``index`` and write its files; returns the depth pixels clipped (0 by construction of
        depth_scale)."""
        path = self.path
        out, _ = renderer.render(path.cameras.subset([index]), float(path.near[index]), float(path.far[index]),
                                 excluded_views(path, index))
        depth = out.depth.double().cpu().numpy()
        valid = out.opacity.cpu().numpy() >= MIN_DEPTH_OPACITY
        if self.depth_format == "npy":
            stored, clipped = depth_to_float(depth / self.similarity_scale, valid), 0
        else:
            stored, clipped = depth_to_uint16(depth / self.similarity_scale, valid, self.depth_scale)
        write_frame(frame_paths(self.out_dir, index, self.depth_format), out.rgb.float().cpu().numpy(), stored,
                    depth_to_turbo(depth, valid, float(path.near.min()), float(path.far.max())))
        return clipped

    def done(self, index: int) -> bool:
        return frame_paths(self.out_dir, index, self.depth_format).all_exist()
