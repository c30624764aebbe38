"""Probe data: synth-5 scenes whose rooms hold thin furniture (railings along the walls, table and chair frames).

Issue 27 (round 14): beer's error sits in its photos' top third, where a dark railing and table legs stand far
behind the can; synth-5 puts fences and thin occluders only in forward-facing and hand-held grid scenes, between
the camera and the subject, and furnishes rooms with solid shapes. This script renders synth-5 datasets with
``synth.enclosures._room`` wrapped, in this process only, so that every room also gets 3-8 thin pieces near its
walls (most behind the subject for orbit cameras), and with rooms drawn for 80 % of the scenes instead of 40 %. The
manifest still says synth-5 (same options, other pixels): these folders are probe data, not a release of synth.

    OMP_NUM_THREADS=1 python3 bench/thin_room_data.py data/thin/t360 --layout 360 --scenes 40 --seed 700
    OMP_NUM_THREADS=1 python3 bench/thin_room_data.py data/thin/thand --layout handheld --scenes 40 --seed 701
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.synth import CaptureOptions, SynthOptions, generate_dataset  # noqa: E402
from insertnerf_cli.synth import enclosures, geometry  # noqa: E402
from insertnerf_cli.synth.builder import Builder  # noqa: E402

ROOM_SHARE = (0.8, 0.1, 0.1)  # room, sky, street
# Scene units; the subject has radius 1, and beer's railing and table stand several times the can's height.
RAILING_HEIGHT = (1.2, 3.0)
FRAME_SCALE = (1.5, 4.0)  # rods' frames have half-extents 0.2-0.5: tables and chairs 0.6-4 units across


def add_thin_furniture(b: Builder, rng: np.random.Generator, room: enclosures.Enclosure) -> None:
    """3-8 railings (along a wall) or rod frames (tables, chairs) standing on the floor between the subject's
    surroundings and the walls (some between an orbit camera and the subject, most behind it)."""
    for _ in range(int(rng.integers(3, 9))):
        wall = int(rng.integers(4))  # +x, -x, +y, -y
        along, inset = rng.uniform(-0.4, 0.4), rng.uniform(0.2, 0.46)
        spot = np.array([[inset, along], [-inset, along], [along, inset], [along, -inset]])[wall]
        xy = room.center + spot * room.size
        if rng.random() < 0.5:
            shape = geometry.fence(rng)  # along x, one unit long, base at z = 0
            height = float(np.ptp(shape.mesh.vertices[:, 2]))
            scale = min(rng.uniform(*RAILING_HEIGHT) / height, 0.8 * float(room.size.min()))
            rotation = Rotation.from_euler("z", math.pi / 2 if wall < 2 else 0.0).as_matrix()  # along the wall
            b.add(shape, rotation, np.array([xy[0], xy[1], room.floor]), float(scale),
                  material=b.material(enclosures.random_material(rng, glossy=False)))
        else:
            shape = geometry.rods(rng)
            b.stand(shape, xy, float(rng.uniform(*FRAME_SCALE)), room.floor, upright=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--layout", default="360")
    parser.add_argument("--scenes", type=int, default=40)
    parser.add_argument("--views", type=int, default=24)
    parser.add_argument("--test-views", type=int, default=3)
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    room = enclosures._room

    def thin_room(b, rng, floor, lo, hi):
        enclosure = room(b, rng, floor, lo, hi)
        add_thin_furniture(b, rng, enclosure)
        return enclosure

    enclosures._room = thin_room
    enclosures._KIND_P = ROOM_SHARE
    options = SynthOptions(scenes=args.scenes, views=args.views, test_views=args.test_views, resolution=200,
                           layout=args.layout, seed=args.seed, capture=CaptureOptions(photo=True))
    generate_dataset(args.out, options, workers=args.workers)


if __name__ == "__main__":
    main()
