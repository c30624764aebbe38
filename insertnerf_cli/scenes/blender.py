"""NeRF-Synthetic / Blender scenes: ``transforms_{train,val,test}.json`` beside the images.

OpenGL camera-to-world per frame; ``camera_angle_x`` (or our ``fl_x fl_y cx cy w h``); file paths relative
to the JSON, often without extension (``.png`` is added). Splits are kept; RGBA is composited on the
background on load.
"""
from __future__ import annotations

from pathlib import Path

from insertnerf_cli.scenes.base import Scene
from insertnerf_cli.scenes.common import ReadViews, assemble
from insertnerf_cli.scenes.jsonframes import depth_scale, layout_key, load_json, read_frames

SPLITS = ("train", "val", "test")


def split_files(root: Path) -> dict[str, Path]:
    """The transforms_<split>.json files present in ``root``, by split name."""
    return {s: root / f"transforms_{s}.json" for s in SPLITS if (root / f"transforms_{s}.json").is_file()}


def read_blender(root: Path, background: tuple[float, float, float]) -> Scene:
    files = split_files(root)
    metas = {name: load_json(path) for name, path in files.items()}
    frames = read_frames(root, [(files[n], metas[n]) for n in metas], default_ext=".png")
    splits, start = {}, 0
    for name, meta in metas.items():
        splits[name] = list(range(start, start + len(meta["frames"])))
        start += len(meta["frames"])
    first, source = next(iter(metas.values())), next(iter(files.values()))
    views = ReadViews(root=root, paths=frames.paths, K=frames.K, c2w=frames.c2w, format="blender",
                      sizes=frames.sizes, near=frames.near, far=frames.far, splits=splits,
                      layout=layout_key(first, source), depth_paths=frames.depth_paths,
                      depth_scale=depth_scale(first, frames, source), distortion=frames.distortion,
                      source=source if len(files) == 1 else None)
    return assemble(views, background)
