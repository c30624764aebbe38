"""A training set of synth scenes twice each: as they are, and with LLFF-like bounds per view (issue 27, round 6).

LLFF's bounds are the 0.1 and 99.9 percentiles of the depths of the points a photo sees, so a real capture's far
bound can cut off its background; synth writes one loose pair per scene. The copy (`tight_NAME`: links to the
scene's files, its transforms_*.json rewritten with per-frame near/far from the exact depth) lets training see both.

    python3 bench/tight_bounds_data.py data/trainmix data/traintight [--layout object] [--far-percentile 90]

``--far-percentile`` below LLFF's 99.9 puts that share of each view's surface beyond its far bound, as LLFF's bounds
do where COLMAP finds no points on a plain or blurred background (round 7: what the infinity sample must carry).
"""
import argparse
import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.scenes.geometry import POINT_PERCENTILES, bounds_from_depths  # noqa: E402  (LLFF's)

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("source", type=Path, help="folder of scene folders (or links to them)")
parser.add_argument("out", type=Path, help="new folder: a link to each scene plus its tight_ copy")
parser.add_argument("--layout", default=None, help="make tight copies of this layout's scenes only (object, forward)")
parser.add_argument("--far-percentile", type=float, default=None,
                    help="far bound at this percentile of each view's depth (default: LLFF's, 99.9)")
parser.add_argument("--prefix", default="tight_", help="name prefix of the copies")
args = parser.parse_args()
percentiles = (POINT_PERCENTILES[0], POINT_PERCENTILES[1] if args.far_percentile is None else args.far_percentile)
src, dst = args.source, args.out
dst.mkdir(exist_ok=True)
for link in sorted(src.iterdir()):
    scene = link.resolve()
    if not (dst / link.name).exists():
        os.symlink(scene, dst / link.name)
    if args.layout and json.loads((scene / "transforms_train.json").read_text()).get("layout") != args.layout:
        continue
    out = dst / f"{args.prefix}{link.name}"
    out.mkdir(exist_ok=True)
    for entry in scene.iterdir():
        if entry.name.startswith("transforms_") or (out / entry.name).exists():
            continue
        os.symlink(entry, out / entry.name)
    for tf in scene.glob("transforms_*.json"):
        meta = json.loads(tf.read_text())
        scale = float(meta.get("depth_unit_scale_factor", 0.001))
        for frame in meta["frames"]:
            d = cv2.imread(str(scene / frame["depth_file_path"]), cv2.IMREAD_UNCHANGED).astype(np.float64) * scale
            loose = torch.tensor([[meta["near"]], [meta["far"]]], dtype=torch.float64)  # [2, 1]
            near, far = (float(b[0]) for b in bounds_from_depths([torch.from_numpy(d)], (loose[0], loose[1]),
                                                                 percentiles))
            frame["near"], frame["far"] = near, max(far, near * 1.01)  # a flat view must keep a depth range
        (out / tf.name).write_text(json.dumps(meta))
print(len(list(dst.iterdir())))
