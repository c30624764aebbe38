"""Score the SfM-depth blend's rules offline: render once, then try constants and rules in seconds.

Issue 27 (rounds 36-37): every rule of `insertnerf_cli/prior_blend.py` acts after the generator's frame, so a probe
need not render again. `dump` runs `insertnerf eval` with a process-local hook that saves, for every held-out view
and reference count, what `blend_at_prior` receives (the generator's frame, the encoded references without their
U-Net features, the camera, the SfM prior and its splats, the far bound, the background flag) and the photo.
`score` runs `blend_at_prior` again on those records, once as shipped and once per variant, and prints each
dump's mean PSNR at each count, as shipped and as each variant's difference. A variant sets module constants of
prior_blend (`BACKGROUND_MARGIN=2`, several joined by `+`) or runs a Python file (`exec:FILE`, run with `pb` bound to
prior_blend and `torch`; it may replace prior_blend's functions or add constants that later parts set). A constant
read only as a default argument (MIX_POWER in mix_share, WINDOW_FRACTION in patch_mean) is bound at import:
replace the function instead. Each variant is undone before the next. A view whose frame has no SfM points never
reaches the blend: its record holds its render alone, which every variant keeps. The shipped scores equal eval's
to the last digit: eval scores the blend's output unrounded.

    OMP_NUM_THREADS=1 python3 bench/blend_rules.py dump /work/shared/realdata/room runs/blend/room --views 3,10
    OMP_NUM_THREADS=1 python3 bench/blend_rules.py score runs/blend/room runs/blend/flower \\
        --variant MARGIN=1.2 --variant FILL_POWER=2+MARGIN=1.2

The dumps hold plain tensors and load with weights_only=True: about 4 MB per reference view of each record at
256 px (the photos at twice the frame's size, the occlusion maps), so room at 3 and 10 views takes 0.3 GB.
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import math
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import insertnerf_cli.evaluate as evaluate  # noqa: E402
import insertnerf_cli.prior_blend as prior_blend  # noqa: E402
from insertnerf_cli.metrics import psnr  # noqa: E402

# The dataclasses a record may hold, rebuilt by name on load (nothing else is imported from a dump).
KINDS = ("insertnerf_cli.model.types:EncodedViews", "insertnerf_cli.model.occlusion:Occlusion",
         "insertnerf_cli.cameras:Cameras", "insertnerf_cli.render:ImageOutput")


ADDED = "__names_before_exec__"
RECORDS = "[0-9][0-9][0-9][0-9].pt"  # a dump's own files: NNNN.pt in the order eval scored them


def flat(value):
    """A dataclass tree as nested dicts of tensors and plain values (what weights_only=True loads)."""
    if dataclasses.is_dataclass(value):
        kind = f"{type(value).__module__}:{type(value).__qualname__}"
        assert kind in KINDS, kind
        return {"__kind__": kind, **{f.name: flat(getattr(value, f.name)) for f in dataclasses.fields(value)}}
    if isinstance(value, tuple):
        return {"__tuple__": [flat(v) for v in value]}
    return value


def unflat(value):
    """flat()'s inverse."""
    if isinstance(value, dict) and "__kind__" in value:
        module, name = value["__kind__"].split(":")
        if value["__kind__"] not in KINDS:
            raise ValueError(f"unexpected kind {value['__kind__']!r} in a dump")
        cls = getattr(importlib.import_module(module), name)
        return cls(**{k: unflat(v) for k, v in value.items() if k != "__kind__"})
    if isinstance(value, dict) and "__tuple__" in value:
        return tuple(unflat(v) for v in value["__tuple__"])
    return value


def dump(scene: str, out: Path, eval_args: list[str]) -> None:
    """Run eval on ``scene`` and save one record per rendered view and count under ``out`` (NNNN.pt)."""
    import click

    from insertnerf_cli.group import cli
    from insertnerf_cli.view_renderer import ViewRenderer

    if out.is_dir() and any(out.glob(RECORDS)):
        raise SystemExit(f"{out} holds a dump already; choose another folder or remove its records first")
    shipped, shipped_psnr, shipped_render = prior_blend.blend_at_prior, evaluate.psnr, ViewRenderer.render
    pending: dict = {}
    written = [0]

    def hooked_render(self, *args, **kwargs):
        pending.clear()
        frame, refs = shipped_render(self, *args, **kwargs)
        pending["views"], pending["render"] = len(refs), frame.rgb
        return frame, refs

    def hooked_blend(frame, encoded, camera, prior, far, splatted=None, background=False):
        light = dataclasses.replace(encoded, features=())  # the blend never reads the U-Net features
        pending.update(frame=flat(frame), encoded=flat(light), camera=flat(camera), prior=prior, far=far,
                       splatted=splatted, background=background)
        return shipped(frame, encoded, camera, prior, far, splatted, background)

    def hooked_psnr(render, truth):
        # A frame without SfM points never reaches the blend: its record holds the render alone.
        record = pending if "frame" in pending else {"views": pending["views"], "render": pending["render"]}
        out.mkdir(parents=True, exist_ok=True)  # only once eval has rendered: a bad argument leaves no folder
        torch.save(dict(record, truth=torch.as_tensor(truth)), out / f"{written[0]:04d}.pt")
        written[0] += 1
        pending.clear()
        return shipped_psnr(render, truth)

    prior_blend.blend_at_prior, evaluate.psnr, ViewRenderer.render = hooked_blend, hooked_psnr, hooked_render
    try:
        cli.main(["eval", scene, *eval_args], prog_name="insertnerf", standalone_mode=False)
    except click.ClickException as err:
        err.show()
        raise SystemExit(err.exit_code) from None
    print(f"{written[0]} records in {out}", file=sys.stderr)


def apply_variant(variant: str) -> dict:
    """Set a variant's constants (NAME=value, joined by +) or run its file (exec:FILE); returns what to undo
    (undo_variant)."""
    undo: dict = {}
    for part in filter(None, variant.split("+")):
        if part.startswith("exec:"):
            undo.setdefault(ADDED, set(vars(prior_blend)))
            for k, v in vars(prior_blend).items():
                undo.setdefault(k, v)
            exec(compile(Path(part[5:]).read_text(), part[5:], "exec"), {"pb": prior_blend, "torch": torch})
            continue
        name, value = part.split("=", 1)
        if not hasattr(prior_blend, name):
            raise SystemExit(f"prior_blend has no {name}")
        undo.setdefault(name, getattr(prior_blend, name))
        setattr(prior_blend, name, type(getattr(prior_blend, name))(float(value)))
    return undo


def score(records: list[dict], variant: str) -> dict[int, float]:
    """Mean PSNR by reference count of blend_at_prior under ``variant`` ("" = as shipped) on ``records``."""
    undo = apply_variant(variant)
    try:
        by_count = defaultdict(list)
        for r in records:
            if "frame" not in r:  # no SfM points in this frame: no blend to vary
                by_count[r["views"]].append(psnr(r["render"].double(), r["truth"]))
                continue
            out = prior_blend.blend_at_prior(r["frame"], r["encoded"], r["camera"], r["prior"], r["far"],
                                             r["splatted"], r["background"])
            by_count[r["views"]].append(psnr(out.rgb.double(), r["truth"]))
        return {n: float(np.mean([p for p in v if math.isfinite(p)])) for n, v in sorted(by_count.items())}
    finally:
        undo_variant(undo)


def undo_variant(undo: dict) -> None:
    """Restore prior_blend as it was before apply_variant (names an exec added are removed)."""
    before = undo.pop(ADDED, None)
    for k, v in undo.items():
        setattr(prior_blend, k, v)
    for k in set(vars(prior_blend)) - (before if before is not None else set(vars(prior_blend))):
        delattr(prior_blend, k)


def load(folder: Path) -> list[dict]:
    """The records of one dump, in the order eval wrote them (other .pt files in the folder are left alone)."""
    records = []
    for path in sorted(folder.glob(RECORDS)):
        raw = torch.load(path, weights_only=True)
        records.append({k: unflat(v) for k, v in raw.items()})
    return records


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    d = sub.add_parser("dump", help="run eval and save the blend's inputs")
    d.add_argument("scene")
    d.add_argument("out", type=Path)
    s = sub.add_parser("score", help="score variants on dumps")
    s.add_argument("dumps", type=Path, nargs="+")
    s.add_argument("--variant", action="append", default=[], help="NAME=value[+NAME=value...] or exec:FILE")
    args, rest = parser.parse_known_args()
    if args.command == "dump":
        dump(args.scene, args.out, rest)
        return
    if rest:
        parser.error(f"unknown arguments {rest}")
    data = {folder.name: load(folder) for folder in args.dumps}
    shipped = {name: score(records, "") for name, records in data.items()}
    print("shipped: " + "  ".join(f"{name} " + " / ".join(f"{v:.3f}" for v in s.values())
                                  for name, s in shipped.items()), flush=True)
    for variant in args.variant:
        cells = []
        for name, records in data.items():
            got = score(records, variant)
            cells.append(f"{name} " + " / ".join(f"{got[n] - shipped[name][n]:+.3f}" for n in got))
        print(f"{variant}: " + "  ".join(cells), flush=True)


if __name__ == "__main__":
    main()
