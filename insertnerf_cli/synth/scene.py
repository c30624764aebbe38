"""Render one synthetic scene into a Blender-format folder.

Folder contents: ``transforms_train.json`` / ``transforms_test.json`` (OpenGL c2w, ``fl_x fl_y cx cy w h``,
our ``near``/``far``/``layout`` keys), RGB PNGs ``train/r_000.png``..., ground-truth z-depth as uint16 PNGs in
millimetres of scene units ``depth/<split>/r_000.png`` (0 = no surface) referenced by ``depth_file_path``,
and ``scene.json`` (what was drawn, for people and for rebuilding).
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from insertnerf_cli.cameras.camera import Cameras
from insertnerf_cli.scenes.writers import write_blender_transforms
from insertnerf_cli.synth.capture import CaptureOptions, develop, draw_settings
from insertnerf_cli.synth.compose import COMPOSERS, compose_360
from insertnerf_cli.synth.layouts import FOV_RANGE, RIGS, Frame, held_out_indices, random_frame
from insertnerf_cli.synth.raycast import build_scene_mesh
from insertnerf_cli.synth.render import auto_exposure, render_view
from insertnerf_cli.synth.world import World, exposed

LAYOUTS = ("object", "forward", "360", "handheld")
# Depth files store millimetres of scene units in uint16 (nerfstudio's convention).
DEPTH_SCALE = 0.001
# Margins that turn the rendered depth range into near/far bounds valid for every view.
_NEAR_MARGIN, _FAR_MARGIN = 0.9, 1.1
# Independent random streams of a scene, so that e.g. more views do not change the world.
_LAYOUT, _WORLD, _RIG, _CAPTURE, _VIEW = range(5)


@dataclass(frozen=True)
class SceneSpec:
    """Everything that decides one scene's pixels: rendering it twice gives identical files.

    Attributes:
        index: scene number in its dataset; with ``seed`` it seeds every random stream of the scene.
        seed: the dataset seed (>= 0).
        layout: "object", "forward", "360" or "handheld".
        views: views rendered, of which ``test_views`` are held out in transforms_test.json.
        resolution: long side of the images in pixels.
        aspects: image aspect ratios (long / short) to draw from.
        capture: capture effects switched on.
        fov: range of the long side's field of view, degrees (the default is left out of the JSON, so specs
            written before it existed read back the same).
        supports: in the 360 layout, the subject stands on a support (compose.compose_360); left out of the JSON
            when off, as ``fov``.
    """

    index: int
    seed: int
    layout: str
    views: int
    test_views: int
    resolution: int
    aspects: tuple[float, ...]
    capture: CaptureOptions
    fov: tuple[float, float] = FOV_RANGE
    supports: bool = False

    @property
    def name(self) -> str:
        return f"scene_{self.index:05d}"

    def to_json(self) -> dict:
        return defaults_left_out({**asdict(self), "aspects": list(self.aspects), "name": self.name}, self.fov,
                                 self.supports)

    @staticmethod
    def from_json(data: dict) -> "SceneSpec":
        fields = {k: v for k, v in data.items() if k != "name"}
        return SceneSpec(**{**fields, "aspects": tuple(fields["aspects"]), "fov": tuple(fields.get("fov", FOV_RANGE)),
                            "capture": CaptureOptions(**fields["capture"])})


def defaults_left_out(fields: dict, fov: tuple[float, float], supports: bool = False) -> dict:
    """``fields`` with the field-of-view range as a list, or without it where it is the default, and without
    ``supports`` where it is off: a dataset made before these could be chosen keeps its manifest, so a run of
    today's synth resumes it."""
    left_out = ({"fov"} if tuple(fov) == FOV_RANGE else set()) | (set() if supports else {"supports"})
    kept = {k: v for k, v in fields.items() if k not in left_out}
    return kept if "fov" in left_out else {**kept, "fov": list(fov)}


def stream(seed: int, index: int, *key: int) -> np.random.Generator:
    """The random generator of one stream of one scene (no global state)."""
    return np.random.default_rng(np.random.SeedSequence([seed, index], spawn_key=key))


def draw_layout(seed: int, index: int, layouts: tuple[str, ...] = LAYOUTS) -> str:
    """The layout of scene ``index`` of a "mixed" dataset."""
    return str(layouts[stream(seed, index, _LAYOUT).integers(len(layouts))])


@dataclass(frozen=True)
class RenderedScene:
    """Summary of a rendered scene: views written, wall seconds, near/far bounds."""

    name: str
    views: int
    seconds: float
    near: float
    far: float


def scene_world(spec: SceneSpec) -> World:
    """The world of a scene (before exposure)."""
    rng = stream(spec.seed, spec.index, _WORLD)
    return compose_360(rng, supports=True) if spec.supports and spec.layout == "360" else COMPOSERS[spec.layout](rng)


def scene_cameras(spec: SceneSpec, world: World) -> tuple[Cameras, Frame]:
    """All ``spec.views`` cameras of a scene, in view order (held-out views included), and their frame."""
    rig_rng = stream(spec.seed, spec.index, _RIG)
    frame = random_frame(rig_rng, spec.resolution, spec.aspects, spec.fov)
    return RIGS[spec.layout](rig_rng, world.stage, frame, spec.views), frame


def scene_splits(spec: SceneSpec) -> dict[str, list[int]]:
    """View indices of the train and test splits (each split's files are numbered in this order)."""
    test = set(held_out_indices(spec.views, spec.test_views))
    return {"train": [i for i in range(spec.views) if i not in test], "test": sorted(test)}


def render_scene(spec: SceneSpec, folder: Path) -> RenderedScene:
    """Render ``spec`` into ``folder`` (created; the caller renames it into place when this returns)."""
    start = time.perf_counter()
    world = scene_world(spec)
    mesh = build_scene_mesh(world)
    cameras, frame = scene_cameras(spec, world)
    exposure = auto_exposure(mesh, world, cameras)
    world = exposed(world, exposure)
    settings = draw_settings(stream(spec.seed, spec.index, _CAPTURE), spec.capture)
    splits = scene_splits(spec)
    depth_range = [np.inf, 0.0]
    captured: dict[str, list[dict]] = {}
    for split, indices in splits.items():
        for k, i in enumerate(indices):
            view = render_view(mesh, world, cameras[[i]])
            rgb, capture = develop(view.radiance, settings, stream(spec.seed, spec.index, _VIEW, i))
            captured.setdefault(split, []).append(capture.to_json())
            _write_png(folder / split / f"r_{k:03d}.png", rgb[..., ::-1])
            _write_png(folder / "depth" / split / f"r_{k:03d}.png", encode_depth(view.depth))
            valid = view.depth[view.depth > 0]
            if len(valid):
                depth_range = [min(depth_range[0], valid.min()), max(depth_range[1], valid.max())]
    near, far = _bounds(depth_range)
    facing = "forward" if spec.layout == "forward" or world.stage.style == "grid" else "object"
    for split, indices in splits.items():
        if indices:
            _write_transforms(folder, split, cameras[indices], spec, near, far, facing)
    record = {"spec": spec.to_json(), "world": world.description, "exposure": exposure,
              "frame": asdict(frame), "capture": settings.to_json(), "views": captured, "near": near, "far": far}
    (folder / "scene.json").write_text(json.dumps(record, indent=2) + "\n")
    return RenderedScene(spec.name, spec.views, time.perf_counter() - start, near, far)


def _bounds(depth_range: list[float]) -> tuple[float, float]:
    if not np.isfinite(depth_range[0]):  # nothing was hit in any view
        return 0.1, 10.0
    return float(depth_range[0] * _NEAR_MARGIN), float(depth_range[1] * _FAR_MARGIN)


def encode_depth(depth: np.ndarray) -> np.ndarray:
    """z-depth [H, W] in scene units -> uint16 millimetres (0 stays 0 = no surface)."""
    return np.clip(np.rint(depth / DEPTH_SCALE), 0, np.iinfo(np.uint16).max).astype(np.uint16)


def _write_png(path: Path, image: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise OSError(f"could not write {path}")


def _write_transforms(folder: Path, split: str, cameras: Cameras, spec: SceneSpec, near: float, far: float,
                      facing: str) -> None:
    """One split's transforms file; ``facing`` is the readers' layout ("forward" or "object")."""
    names = [f"{split}/r_{k:03d}.png" for k in range(len(cameras))]
    depths = [{"depth_file_path": f"depth/{split}/r_{k:03d}.png"} for k in range(len(cameras))]
    extra = {"layout": facing, "depth_unit_scale_factor": DEPTH_SCALE,
             "synth_layout": spec.layout}
    write_blender_transforms(folder / f"transforms_{split}.json", cameras, names, near=near, far=far, extra=extra,
                             frame_extras=depths)

