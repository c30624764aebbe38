"""What each reference shows where one held-out view's render is wrong (issue 27, round 15).

Renders the held-out view as eval does (the shipped fast generator or --checkpoint, 10 references, 256 px), takes
the pixels it misses by more than WRONG in some channel below the image's top third (--rows all: everywhere), and
prints, per reference, the share of those pixels it sees at the rendered depth and its mean colour there, beside
the photo's and the render's. References that agree with each other and not with the photo lend the error (an
occluder, a shadow that only some of them hold).

    OMP_NUM_THREADS=2 python3 bench/reference_colours.py --capture beer --view 0048.jpg
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer, checkpoint_path, load_model  # noqa: E402
from insertnerf_cli.views import held_out_views  # noqa: E402
from sweep_probe import REALDATA, WRONG, reference_colours  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capture", default="beer")
    parser.add_argument("--root", type=Path, default=REALDATA)
    parser.add_argument("--view", required=True, help="file name of a held-out view, e.g. 0048.jpg")
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--rows", choices=("below-top-third", "all"), default="below-top-third")
    parser.add_argument("--checkpoint", type=Path, default=None, help="default: the bundled fast generator")
    args = parser.parse_args()
    scene, _ = normalize_scene(load_scene(args.root / args.capture))
    held = held_out_views(scene)
    matches = [i for i in held if Path(scene.names[i]).name == args.view]
    if not matches:
        sys.exit(f"{args.view} is not a held-out view of {args.capture}: "
                 f"{', '.join(Path(scene.names[i]).name for i in held)}")
    index = matches[0]
    size = scene.size_for(256)
    renderer = ViewRenderer(load_model(checkpoint_path(args.checkpoint), "cpu"), scene, size, args.views)
    camera = scene.cameras.subset([index]).rescale(*size).to(dtype=torch.float64)
    truth = torch.from_numpy(scene.load_image(index, *size).astype(np.float64))  # [H, W, 3]
    out, refs = renderer.render(camera, float(scene.near[index]), float(scene.far[index]), held, args.views)
    render, depth = out.rgb.double().cpu(), out.depth.double().cpu()
    wrong = (render - truth).abs().amax(-1) > WRONG  # [H, W]
    if args.rows != "all":
        wrong[: size[0] // 3] = False
    rows, cols = torch.nonzero(wrong, as_tuple=True)
    print(f"{args.capture} {args.view}: {len(rows)} pixels missed by > {WRONG}; photo "
          f"{truth[rows, cols].mean(0).numpy().round(2)}, render {render[rows, cols].mean(0).numpy().round(2)}")
    if not len(rows):
        return
    uv = torch.stack([cols, rows], 1).to(torch.float64) + 0.5
    points = camera.unproject(uv[None], depth[rows, cols][None])[0]  # [P, 3] at the rendered depth
    images = torch.from_numpy(np.stack([scene.load_image(r, *size) for r in refs]).astype(np.float64))
    colours, seen = reference_colours(images, scene.cameras.subset(refs).rescale(*size).to(dtype=torch.float64),
                                      points)
    for k, ref in enumerate(refs):
        shown = colours[k][seen[k]].mean(0).numpy().round(2) if seen[k].any() else "-"
        print(f"  reference {Path(scene.names[ref]).name}: sees {float(seen[k].double().mean()) * 100:.0f}%, "
              f"mean colour {shown}")


if __name__ == "__main__":
    main()
