"""The repeated-texture trap of formats.md, reproduced: does the pose check of `insertnerf poses` catch it?

    python3 bench/poses_trap.py                       # 24 views at 640x480, faces share patches offset by 0.5
    python3 bench/poses_trap.py --offset 0.0          # identical faces

Scene: a 2x2x2 cube on a ground plane, orbited by the cameras. Each cube face is textured with a window of
one shared 2-D texture, the windows shifted by ``--offset`` units per face, so different faces carry overlapping
copies of the same patches (the ground's texture is unique). COLMAP registers every view with a sub-pixel
reprojection error, yet the trajectory comes out folded. The script runs ``estimate_poses`` with
``allow_inconsistent=True`` so that it finishes, then prints the true pose errors next to the check's verdict.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]  # the package, and the scenes the tests share (textured_scenes)

from textured_scenes import orbit_cameras, pose_errors, render, solid_texture  # noqa: E402

from insertnerf_cli.poses.estimate import PosesOptions, estimate_poses  # noqa: E402

CUBE_HALF = 1.0


def trap_mesh() -> tuple[trimesh.Trimesh, int]:
    """The cube and a thin ground slab under it; returns the mesh and the number of cube triangles."""
    cube = trimesh.creation.box(extents=[2 * CUBE_HALF] * 3)
    ground = trimesh.creation.box(extents=[12.0, 12.0, 0.01])
    ground.apply_translation([0.0, 0.0, -CUBE_HALF - 0.005])
    return trimesh.util.concatenate([cube, ground]), len(cube.faces)


def folded_colouring(mesh: trimesh.Trimesh, cube_faces: int, offset: float):
    """Cube hits are coloured by their 2-D face coordinates shifted by ``offset`` per face; the rest by 3-D."""
    normals = mesh.face_normals

    def colouring(hits: np.ndarray, tri: np.ndarray) -> np.ndarray:
        n = normals[tri]
        axis = np.abs(n).argmax(1)
        face = 2 * axis + (n[np.arange(len(n)), axis] > 0)  # 0..5, one per cube side
        planar = np.zeros_like(hits)
        for a in range(3):
            u, v = [b for b in range(3) if b != a]
            sel = axis == a
            planar[sel, 0] = hits[sel, u] + offset * face[sel]
            planar[sel, 1] = hits[sel, v]
        on_cube = tri < cube_faces
        rgb = solid_texture(0.5 * hits + 7.0, 3)  # ground: unique, coarser texture
        rgb[on_cube] = solid_texture(planar[on_cube], 0)
        return rgb

    return colouring


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--views", type=int, default=24)
    parser.add_argument("--offset", type=float, default=0.5)
    args = parser.parse_args()
    mesh, cube_faces = trap_mesh()
    cameras = orbit_cameras(args.views, (480, 640), 4.5, fov_deg=60.0, height=lambda a: 1.5)
    images = render(mesh, cameras, folded_colouring(mesh, cube_faces, args.offset))
    with tempfile.TemporaryDirectory() as tmp:
        names = [f"view_{i:03d}.png" for i in range(args.views)]
        (Path(tmp) / "images").mkdir()
        for name, img in zip(names, images):
            cv2.imwrite(str(Path(tmp) / "images" / name), img[..., ::-1])
        result = estimate_poses(Path(tmp) / "images", Path(tmp) / "scene", PosesOptions(allow_inconsistent=True))
    truth = cameras.subset([names.index(n) for n in result.registered])
    rot_err, centre_err = pose_errors(truth, result.cameras)
    print(f"registered        {len(result.registered)}/{args.views}, reprojection "
          f"{result.mean_reprojection_error:.2f} px")
    print(f"true errors       rotation median {np.median(rot_err):.2f} deg (max {rot_err.max():.2f}), centre "
          f"median {100 * np.median(centre_err) / 4.5:.1f} % of the orbit radius")
    print(f"pose check        {'PASSED' if result.check.passed else 'FAILED'}: {result.check.summary()}")
    wrong = np.median(rot_err) > 1.0
    print("verdict           " + ("caught" if wrong and not result.check.passed else
                                  "false alarm" if not wrong and not result.check.passed else
                                  "MISSED" if wrong else "correct poses, check passed"))


if __name__ == "__main__":
    main()
