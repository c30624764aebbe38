"""What the command tests share: a tiny Blender scene and a tiny random-init checkpoint to run the commands on,
the command run through click's CliRunner, and checks of what a command said or wrote."""
from __future__ import annotations

import math
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch
from click.testing import CliRunner, Result

from insertnerf_cli.cameras.camera import Cameras, intrinsics
from insertnerf_cli.cli.main import cli
from insertnerf_cli.config import ModelConfig
from insertnerf_cli.model import InsertNeRF
from insertnerf_cli.model.checkpoint import save_checkpoint
from insertnerf_cli.rendering.camera_paths import look_at
from insertnerf_cli.scenes import write_blender_transforms

HEIGHT, WIDTH = 24, 32
# Tiny network: CLI mechanics only, random weights are fine.
TINY = dict(encoder_widths=(4, 4, 4, 4), feature_dims=(4, 4, 4), nerf_width=8, appearance_width=8, film_hidden=8,
            samples_coarse=8, samples_fine=8, aggregate_hidden=4)


def ring_cameras(n: int, radius: float = 2.0) -> Cameras:
    """n cameras on a ring of ``radius`` units around the origin (world z up), looking at it."""
    angles = torch.arange(n, dtype=torch.float64) * 2 * math.pi / n
    eyes = torch.stack([radius * torch.cos(angles), radius * torch.sin(angles),
                        torch.full_like(angles, 0.5 * radius)], dim=-1)
    c2w = look_at(eyes, torch.zeros(3, dtype=torch.float64), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    return Cameras(intrinsics(30.0, 30.0, WIDTH / 2, HEIGHT / 2).expand(n, 3, 3).clone(), c2w, HEIGHT, WIDTH)


def grid_cameras(n: int) -> Cameras:
    """n cameras on a small grid in the plane z = 0, all facing +z: a forward-facing capture."""
    c2w = torch.eye(4, dtype=torch.float64).repeat(n, 1, 1)
    c2w[:, 0, 3] = 0.1 * (torch.arange(n, dtype=torch.float64) % 3)
    c2w[:, 1, 3] = 0.1 * (torch.arange(n, dtype=torch.float64) // 3)
    return Cameras(intrinsics(30.0, 30.0, WIDTH / 2, HEIGHT / 2).expand(n, 3, 3).clone(), c2w, HEIGHT, WIDTH)


def make_scene(root: Path, splits: dict[str, int], layout: str = "object", scale: float = 1.0) -> Path:
    """A Blender-format scene with ``splits`` = {name: views}, cameras on a ring ("object") or a grid
    ("forward"), every length multiplied by ``scale``; images are smooth per-view colour ramps."""
    n = sum(splits.values())
    cams = ring_cameras(n) if layout == "object" else grid_cameras(n)
    cams = cams.transform(torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64), scale)
    start = 0
    for split, count in splits.items():
        names = [f"{split}/r_{i}.png" for i in range(count)]
        for i, name in enumerate(names):
            ramp = np.linspace(0, 1, WIDTH)[None, :, None] * np.array([1.0, 0.5, (start + i) / 16])
            (root / split).mkdir(parents=True, exist_ok=True)
            iio.imwrite(root / name, (255 * np.broadcast_to(ramp, (HEIGHT, WIDTH, 3))).astype(np.uint8))
        write_blender_transforms(root / f"transforms_{split}.json", cams.subset(range(start, start + count)), names,
                                 near=0.5 * scale, far=4.0 * scale,
                                 extra={"layout": layout})
        start += count
    return root


def make_checkpoint(path: Path, **changes) -> Path:
    """A checkpoint of the TINY network (with ``changes`` to its configuration), initialised with seed 0."""
    torch.manual_seed(0)
    config = ModelConfig(**{**TINY, **changes})
    return save_checkpoint(path, InsertNeRF(config), config)


def run(*args) -> Result:
    """The command line ``args`` (anything str() turns into an argument) through CliRunner; an exception that is
    not a SystemExit is raised, not caught."""
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def render_command(scene: Path, ckpt: Path, out: Path, *extra) -> Result:
    """`insertnerf render` of ``scene`` into ``out`` with ``ckpt`` on the CPU, 16 px, 2 views."""
    return run("render", scene, "--out", out, "--checkpoint", ckpt, "--device", "cpu", "--resolution", 16,
               "--views", 2, *extra)


def one_line_error(result: Result, *fragments: str, exit_code: int = 1) -> str:
    """The one 'Error:' line of a refused command, checked to hold each of ``fragments``: the command exited with
    ``exit_code`` (click's usage errors: 2) and printed no traceback."""
    assert result.exit_code == exit_code, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    lines = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(lines) == 1, result.output
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def video_codec(path: Path) -> str:
    """The codec line ffmpeg reports for a video (e.g. "h264 (High) (avc1 / 0x31637661)")."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    try:
        meta = next(reader)
    finally:
        reader.close()
    return str(meta["codec"])
