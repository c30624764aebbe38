"""Same-run A/B of triangulating SfM points at a scene's own poses (what `render` and `eval` do for a scene that
came without points): this tree against another checkout, on the same scenes, in rotating order.

    git worktree add /tmp/before 446adf0
    python3 bench/triangulate_ab.py --before /tmp/before /work/data/room_nosparse DATA/scene_00000 --rounds 2

Each run is a child process with the tree on PYTHONPATH that loads and normalises the scene as render does and
times `triangulate_points` over every view (wall seconds, points found). Prints each run and the medians per
variant and scene. Take it on idle cores.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
# The child: both layouts of the package (the module moved from insertnerf_cli.triangulate to .sfm.triangulate).
CHILD = """
import sys, time
from pathlib import Path
from insertnerf_cli.scenes import load_scene, normalize_scene
import insertnerf_cli
# By file, not by a failed import: an editable install would find a missing module in the other tree.
if (Path(insertnerf_cli.__file__).parent / "sfm").is_dir():
    from insertnerf_cli.sfm.triangulate import triangulate_points
else:
    from insertnerf_cli.triangulate import triangulate_points
scene, _ = normalize_scene(load_scene(Path(sys.argv[1])))
start = time.perf_counter()
points = triangulate_points(scene, quiet=True)
print(len(scene), scene.cameras.width, scene.cameras.height, len(points), time.perf_counter() - start)
"""


def time_once(tree: Path, scene: Path) -> tuple[str, int, float]:
    """(scene description, points, seconds) of one triangulation with ``tree``'s code."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run([sys.executable, "-c", CHILD, str(scene.resolve())], env=env, cwd=tree, capture_output=True,
                         text=True,
                         check=True).stdout.split()
    views, width, height, points, seconds = out[-5:]
    return f"{views} views of {width}x{height}", int(points), float(seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenes", type=Path, nargs="+", help="posed scene folders without SfM points")
    parser.add_argument("--before", type=Path, required=True, help="a checkout of the code to compare with")
    parser.add_argument("--rounds", type=int, default=1)
    args = parser.parse_args()
    variants = [("before", args.before.resolve()), ("now", HERE)]
    results: dict[tuple[str, Path], list[tuple[int, float]]] = {}
    for round_ in range(args.rounds):
        order = variants if round_ % 2 == 0 else variants[::-1]
        for scene in args.scenes:
            for label, tree in order:
                what, points, seconds = time_once(tree, scene)
                results.setdefault((label, scene), []).append((points, seconds))
                print(f"round {round_ + 1} {label:6s} {scene} ({what}): {points} points, {seconds:.1f} s", flush=True)
    for scene in args.scenes:
        before = statistics.median(s for _, s in results[("before", scene)])
        now = statistics.median(s for _, s in results[("now", scene)])
        print(f"{scene}: before {before:.1f} s, now {now:.1f} s ({now / before:.2f}x)")


if __name__ == "__main__":
    main()
