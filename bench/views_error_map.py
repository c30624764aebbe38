"""Diagnostic: where a held-out view gains or loses from 3 to 10 reference views, by pixel (issue 27, round 22).

Renders the chosen held-out views of a capture as eval does (SfM prior from the non-held-out views, 256 px) with 3
and 10 references, prints each count's references with their distance by the capture's rule and both PSNRs, and
writes one row per view: render at 3 | render at 10 | photo | squared error at 10 minus at 3 (red: 10 views worse,
blue: better, full colour at 0.02).

    OMP_NUM_THREADS=2 python3 bench/views_error_map.py /work/shared/realdata/room img009,img017,img025 /tmp/rim.png
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.triangulate import with_points  # noqa: E402
from insertnerf_cli.view_renderer import ViewRenderer, checkpoint_path, load_model  # noqa: E402
from insertnerf_cli.views import held_out_views, view_distances  # noqa: E402

COUNTS = (3, 10)
FULL_SCALE = 0.02  # squared-error difference shown at full colour


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("names", help="comma-separated parts of held-out image names, e.g. img017,img025")
    parser.add_argument("out", type=Path, help="PNG to write")
    parser.add_argument("--checkpoint", type=Path, default=None)
    args = parser.parse_args()
    scene, _ = normalize_scene(load_scene(args.scene))
    held = held_out_views(scene)
    scene = with_points(scene, [i for i in range(len(scene)) if i not in held])
    size = scene.size_for(256)
    renderer = ViewRenderer(load_model(checkpoint_path(args.checkpoint), "cpu"), scene, size, max(COUNTS))
    rows = []
    for index in held:
        if not any(part in scene.names[index] for part in args.names.split(",")):
            continue
        camera = scene.cameras.subset([index]).rescale(*size)
        truth = scene.load_image(index, *size).astype(np.float64)
        renders = {}
        for n in COUNTS:
            out, refs = renderer.render(camera, float(scene.near[index]), float(scene.far[index]), held, n)
            renders[n] = out.rgb.double().numpy()
            distance = view_distances(scene.cameras.c2w[index], scene.cameras.c2w[refs], renderer.method)
            print(Path(scene.names[index]).stem, n, " ".join(f"{Path(scene.names[r]).stem}:{float(d):.2f}"
                                                            for r, d in zip(refs, distance)))
        errors = {n: ((renders[n] - truth) ** 2).mean(-1) for n in COUNTS}
        print("   PSNR " + " / ".join(f"{-10 * np.log10(errors[n].mean()):.2f}" for n in COUNTS))
        diff = np.clip((errors[COUNTS[1]] - errors[COUNTS[0]]) / FULL_SCALE, -1, 1)
        signed = np.stack([diff.clip(0, 1), np.zeros_like(diff), (-diff).clip(0, 1)], axis=-1)
        rows.append(np.concatenate([renders[COUNTS[0]], renders[COUNTS[1]], truth, signed], axis=1))
    if not rows:
        sys.exit(f"no held-out view of {args.scene} matches {args.names}")
    iio.imwrite(args.out, (np.concatenate(rows, axis=0).clip(0, 1) * 255).astype(np.uint8))


if __name__ == "__main__":
    main()
