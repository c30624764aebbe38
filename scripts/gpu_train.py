"""Train on a lent GPU machine within its limits (docs/training-on-gpu.md): commands of at most 10 minutes, the
machine held at most 30, a few files coming back from $OUT, a run folder carried in to resume.

    python3 scripts/gpu_train.py start --data /tmp/data --scenes 2000 --run runs/gpu --minutes 25 -- --device cuda
    python3 scripts/gpu_train.py poll --run runs/gpu --out "$OUT" --seconds 540

`start` synthesises the dataset on all cores (skipped when DATA already holds a finished `insertnerf synth`
set of at least --scenes scenes), then starts `insertnerf train DATA --out RUN --minutes M` in its own session, so
it outlives the command that started it; with RUN/checkpoints/last.pt present (a carried run folder) it resumes,
and --minutes is the run's total training time, as for `train --resume`. Arguments after `--` go to train.
`poll` waits up to --seconds, printing the newest metrics every --every seconds, and copies the run's
last.pt, best.pt, config.json, metrics.jsonl and splits.json into --out after each print and at the end; it returns early
when the training process has ended. Both print one line per event and exit non-zero with one line on failure.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insertnerf_cli.files.atomic import process_alive  # noqa: E402  (the liveness rule of atomic writes)

INSERTNERF = [sys.executable, "-c", "from insertnerf_cli.cli.main import main; main()"]
BROUGHT_BACK = ("checkpoints/last.pt", "checkpoints/best.pt", "checkpoints/config.json", "metrics.jsonl", "splits.json")


def _pid_file(run: Path) -> Path:
    return run.with_name(run.name + ".pid")  # beside the run folder: train refuses files it did not write


def _log_file(run: Path) -> Path:
    return run.with_name(run.name + ".log")


def _finished_scenes(data: Path) -> int:
    try:
        return len(json.loads((data / "manifest.json").read_text()).get("scenes", []))
    except (OSError, ValueError, AttributeError):
        return 0


def synthesise(data: Path, scenes: int, synth_args: list[str]) -> None:
    if _finished_scenes(data) >= scenes:
        print(f"gpu_train: {data} already holds {_finished_scenes(data)} scenes; not synthesising", flush=True)
        return
    workers = str(os.cpu_count() or 1)
    started = time.monotonic()
    done = subprocess.run([*INSERTNERF, "synth", str(data), "--scenes", str(scenes), "--workers", workers,
                           *synth_args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if done.returncode != 0:
        sys.exit(f"gpu_train: synth failed: {done.stdout.strip().splitlines()[-1:]}")
    print(f"gpu_train: synthesised {scenes} scenes in {time.monotonic() - started:.0f} s on {workers} workers; "
          f"{done.stdout.strip().splitlines()[-1]}", flush=True)


def start(args: argparse.Namespace) -> None:
    run = Path(args.run)
    if _alive(run):
        sys.exit(f"gpu_train: a training process of {run} is still running (pid file {_pid_file(run)}); poll it")
    synthesise(Path(args.data), args.scenes, args.synth_arg)
    resume = (run / "checkpoints" / "last.pt").is_file()
    command = [*INSERTNERF, "train", str(args.data), "--out", str(run), "--minutes", str(args.minutes),
               *(["--resume"] if resume else []), *args.train_args]
    run.parent.mkdir(parents=True, exist_ok=True)
    with open(_log_file(run), "ab") as log:
        proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    _pid_file(run).write_text(str(proc.pid))
    print(f"gpu_train: {'resumed' if resume else 'started'} training (pid {proc.pid}): {' '.join(command[3:])}; "
          f"log {_log_file(run)}", flush=True)


def _alive(run: Path) -> bool:
    try:
        pid = int(_pid_file(run).read_text())
    except (OSError, ValueError):
        return False
    if not process_alive(pid):
        return False
    try:  # a finished child of a still-running caller is a zombie: reap it, it is not training
        return os.waitpid(pid, os.WNOHANG) == (0, 0)
    except ChildProcessError:
        return True


def _newest(run: Path) -> str:
    try:
        lines = (run / "metrics.jsonl").read_text().splitlines()
    except OSError:
        return "no metrics yet"
    train = [json.loads(line) for line in lines if '"split": "train"' in line]
    val = [json.loads(line) for line in lines if '"split": "val"' in line]
    text = "no training step logged yet"
    if train:
        t = train[-1]
        text = f"step {t['step']}, train PSNR {t['psnr']:.2f} dB, {t['rays_per_s']:,.0f} rays/s"
    if val:
        text += f", validation PSNR {val[-1]['psnr']:.2f} dB at step {val[-1]['step']}"
    return text


def bring_back(run: Path, out: Path) -> list[str]:
    out.mkdir(parents=True, exist_ok=True)
    copied = []
    for rel in BROUGHT_BACK:
        source = run / rel
        if source.is_file():
            target = out / Path(rel).name
            shutil.copyfile(source, target.with_suffix(target.suffix + ".part"))
            os.replace(target.with_suffix(target.suffix + ".part"), target)  # a half copy never comes back
            copied.append(target.name)
    return copied


def poll(args: argparse.Namespace) -> None:
    run, out = Path(args.run), Path(args.out)
    deadline = time.monotonic() + args.seconds
    while True:
        alive = _alive(run)
        copied = bring_back(run, out)
        print(f"gpu_train: {'training' if alive else 'not running'}; {_newest(run)}; brought back "
              f"{', '.join(copied) or 'nothing yet'}", flush=True)
        if not alive or time.monotonic() + args.every > deadline:
            break
        time.sleep(args.every)
    if not alive:
        tail = _log_file(run).read_text(errors="replace").strip().splitlines()[-1:] if _log_file(run).exists() else []
        print(f"gpu_train: the training process has ended; last line of its log: {tail}", flush=True)


def stop(args: argparse.Namespace) -> None:
    """Ctrl-C for the background run: train saves a checkpoint and exits."""
    run = Path(args.run)
    if not _alive(run):
        sys.exit(f"gpu_train: no training process of {run} is running")
    os.killpg(int(_pid_file(run).read_text()), signal.SIGINT)
    print("gpu_train: sent Ctrl-C; poll until it has saved and ended", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="action", required=True)
    p = sub.add_parser("start", help="synthesise if needed, then start or resume training in the background")
    p.add_argument("--data", required=True, type=Path)
    p.add_argument("--scenes", type=int, default=2000)
    p.add_argument("--synth-arg", action="append", default=[], help="one more argument for synth (repeatable)")
    p.add_argument("--run", required=True, type=Path)
    p.add_argument("--minutes", type=float, required=True, help="total training minutes of the run")
    p.add_argument("train_args", nargs="*", help="after --: more arguments for train")
    p = sub.add_parser("poll", help="print progress and copy the checkpoints into --out")
    p.add_argument("--run", required=True, type=Path)
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--seconds", type=float, default=540.0)
    p.add_argument("--every", type=float, default=60.0)
    p = sub.add_parser("stop", help="ask the background training to save and stop")
    p.add_argument("--run", required=True, type=Path)
    args = parser.parse_args()
    {"start": start, "poll": poll, "stop": stop}[args.action](args)


if __name__ == "__main__":
    main()
