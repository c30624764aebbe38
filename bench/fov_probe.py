"""Probe: does the generator lose on narrow fields of view? (issue 27, round 27)

synth draws each scene's field of view (long side) from 35-75 degrees by default (`--fov`); mold_gold_cape's
camera sees 26.7 degrees (f = 7,689 px on a 3,648 px square), outside everything the bundled generators trained
on. A camera that frames its subject alike through a longer lens stands farther back (at 26.7 degrees, 1.3 times
as far as at 35 and 2.6 times as far as at 75): its views are nearer to affine and the subject spans a narrower
band of depth (mold_gold_cape: far / near 1.2-1.6). This
makes the same procedural scenes (`insertnerf synth --fov LOW:HIGH`, same seed: the same geometry, materials and
view directions; the rig stands back so that the subject fills the frame alike, up to an enclosure's walls) once
per field-of-view range and scores them with `insertnerf eval`'s protocol.

    OMP_NUM_THREADS=1 python3 bench/fov_probe.py --work /tmp/fov --fovs 35:75,24:30 --scenes 4 --views 3,10
    OMP_NUM_THREADS=1 python3 bench/fov_probe.py --work /tmp/fov --fovs 24:30 --model full   # scenes kept in WORK
    OMP_NUM_THREADS=1 python3 bench/fov_probe.py --work /tmp/fov --fovs 24:30 --object-radius 8.7
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import insertnerf_cli.evaluate as evaluate  # noqa: E402
import insertnerf_cli.scenes.normalize as normalize  # noqa: E402
from insertnerf_cli.group import cli  # noqa: E402
from insertnerf_cli.checkpoint import bundled_checkpoint  # noqa: E402


def make_scenes(out: Path, fov: tuple[float, float], args: argparse.Namespace) -> list[Path]:
    """The probe's scenes with the long side's field of view drawn from ``fov`` (degrees), in ``out``."""
    if len([p for p in out.glob("scene_*") if p.is_dir()]) < args.scenes:
        cli(["synth", str(out), "--scenes", str(args.scenes), "--views", str(args.scene_views), "--test-views", "3",
             "--resolution", str(args.resolution), "--square", "--layout", args.layout, "--seed", str(args.seed),
             "--fov", f"{fov[0]:g}:{fov[1]:g}", "--workers", "1"], prog_name="insertnerf", standalone_mode=False)
    return sorted(p for p in out.glob("scene_*") if p.is_dir())[:args.scenes]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="folder for the scenes (kept, reused)")
    parser.add_argument("--fovs", default="35:75,24:30", help="comma-separated LOW:HIGH ranges, degrees")
    parser.add_argument("--scenes", type=int, default=4)
    parser.add_argument("--scene-views", type=int, default=53)
    parser.add_argument("--resolution", type=int, default=200)
    parser.add_argument("--layout", default="object")
    parser.add_argument("--seed", type=int, default=900001)
    parser.add_argument("--views", default="3,10")
    parser.add_argument("--model", default="fast", help="bundled generator (fast, full)")
    parser.add_argument("--checkpoint", type=Path, default=None, help="weights file in place of --model")
    parser.add_argument("--object-radius", type=float, default=normalize.OBJECT_RADIUS,
                        help="mean camera distance an object scene is normalised to (eval's 4): 8.7 gives 24-30 "
                             "degree scenes the subject size that 35-75 degree ones have")
    parser.add_argument("--exact", action="store_true", help="every ray's own coarse and fine pass (eval --exact)")
    args = parser.parse_args()
    normalize.OBJECT_RADIUS = args.object_radius  # read at load time (normalize_scene)
    counts = tuple(int(n) for n in args.views.split(","))
    checkpoint = args.checkpoint or bundled_checkpoint(args.model)
    for spec in args.fovs.split(","):
        low, high = (float(v) for v in spec.split(":"))
        scenes = make_scenes(args.work / f"fov_{low:g}_{high:g}", (low, high), args)
        per_count = [[] for _ in counts]
        for scene in scenes:
            run = evaluate.run_eval(scene, evaluate.EvalConfig(views=counts if len(counts) > 1 else counts[0],
                                                               checkpoint=checkpoint, exact=args.exact))
            for scores, report in zip(per_count, run.reports):
                scores.append(report.psnr)
            print(f"  {scene.name}: " + " / ".join(f"{r.psnr:.2f}" for r in run.reports), flush=True)
        means = " / ".join(f"{sum(s) / len(s):.2f}" for s in per_count)
        print(f"fov {low:g}-{high:g} deg | {checkpoint.name}{' | exact' if args.exact else ''} | "
              f"object radius {args.object_radius:g} | "
              f"{len(scenes)} scenes | views {args.views} | {means}",
              flush=True)


if __name__ == "__main__":
    main()
