"""Diagnostic: how many SfM points each candidate reference shares with a held-out view's nearest one (issue 27,
round 22; beer's folded poses).

For the first held-out views of a capture with a COLMAP model (beer and room hold one), prints the 20 nearest
references by the capture's rule, each with the share of the nearest reference's points that it observes too.
On beer a view's own pass shares about half and the other half of the folded walk a fifth to a third.

    python3 bench/covisibility_diag.py /work/shared/realdata/beer --held 6
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.scenes import load_scene, normalize_scene  # noqa: E402
from insertnerf_cli.views import held_out_views, nearest_views, view_rule  # noqa: E402

CANDIDATES = 20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("--held", type=int, default=6, help="how many held-out views to print")
    args = parser.parse_args()
    scene, _ = normalize_scene(load_scene(args.scene))
    if scene.points is None or scene.points.observed is None:
        sys.exit(f"{args.scene}: no SfM points with observations (a COLMAP model beside the poses)")
    held = held_out_views(scene)
    observed = [set(o.tolist()) for o in scene.points.observed]
    method = view_rule(scene.layout)
    for index in held[:args.held]:
        refs = nearest_views(scene.cameras.c2w[index], scene.cameras.c2w, CANDIDATES, method, exclude=held)
        anchor = observed[refs[0]]
        cells = [f"{Path(scene.names[r]).stem}:{len(anchor & observed[r]) / max(1, len(anchor)):.2f}" for r in refs]
        print(Path(scene.names[index]).stem, " ".join(cells))


if __name__ == "__main__":
    main()
