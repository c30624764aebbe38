"""How far render's camera path turns beyond the photos: per frame, the angle between its optical axis and that of
the photo nearest it (by position: a forward-facing frame's references are its nearest photos), and of the photo
nearest in angle.

Issue 27 (round 37): a generalizable renderer draws only what its references saw, so a frame that looks where no
photo looked draws walls no reference sees well. LLFF's spiral focus (about 4 x near) turned room's frames 17
degrees on average (21 at most) from the photo nearest each; the focus at which the frames turn least from the
photos beside them keeps them at 0.8 (1.7). The path is built as render builds it (the normalised scene, paths.make_path), not rendered.

    python3 bench/path_turn.py SCENE_DIR [SCENE_DIR ...] [--path spiral] [--frames 30]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.errors import UserError  # noqa: E402
from insertnerf_cli.rendering.camera_paths import make_path  # noqa: E402
from insertnerf_cli.exporters.records import DEFAULT_FRAMES  # noqa: E402
from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402


def turns(frames: torch.Tensor, photos: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Degrees [F] from each frame's axis (OpenCV c2w [F, 4, 4]) to that of the photo nearest it by position, and
    to the nearest photo axis at all (photos: c2w [N, 4, 4])."""
    axes, photo_axes = frames[:, :3, 2].double(), photos[:, :3, 2].double()
    angles = torch.rad2deg(torch.acos((axes @ photo_axes.T).clamp(-1.0, 1.0)))  # [F, N]
    nearest = torch.cdist(frames[:, :3, 3].double(), photos[:, :3, 3].double()).argmin(dim=1)  # [F]
    return angles[torch.arange(len(axes)), nearest].numpy(), angles.min(dim=1).values.numpy()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenes", type=Path, nargs="+")
    parser.add_argument("--path", choices=("orbit", "spiral"), default="spiral")
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES)
    args = parser.parse_args()
    for scene_dir in args.scenes:
        scene, _ = normalize_scene(load_scene(scene_dir))  # the world render builds its paths in
        try:
            path = make_path(args.path, scene.cameras, scene.near, scene.far, args.frames, (60, 80))
        except UserError as err:
            print(f"{scene_dir}: no {args.path}: {err}")
            continue
        beside, any_photo = turns(path.cameras.c2w, scene.cameras.c2w)
        print(f"{scene_dir}: {len(beside)} frames, degrees from the nearest photo's axis: mean {beside.mean():.1f}, "
              f"max {beside.max():.1f}; from the nearest axis of any photo: mean {any_photo.mean():.1f}, "
              f"max {any_photo.max():.1f}")


if __name__ == "__main__":
    main()
