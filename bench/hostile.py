"""Hostile inputs and faults against the real `insertnerf` command, one subprocess per step (issue 12).

    python3 bench/hostile.py                  # every case, one line each, then the summary
    python3 bench/hostile.py --only render    # the cases whose name contains "render" (or a,b: either)
    python3 bench/hostile.py --keep /tmp/h    # build and keep the work folder there (for a post-mortem)
    python3 bench/hostile.py --installed      # run `insertnerf` from PATH instead of this checkout's code

It builds its own tiny inputs (a `synth` dataset of 32 px scenes, a 2-step checkpoint of a tiny model, 16 photos
of a ray-cast room), then runs the cases of bench/hostile_cases.py, bench/hostile_inputs.py,
bench/hostile_finetune.py, bench/hostile_models.py, bench/hostile_races.py (two writers of one output, issue 29)
and bench/hostile_scenefiles.py (damaged scene files, odd photo names, WebP, the bundled weights). What a case
must show comes from the developer brief and issues 12 and 29, not from today's code: bad input ends with a short error (at most 3 lines besides progress bars: the error and a hint) and an exit
status of 1-125; valid input exits 0;
Ctrl-C exits non-zero; no step prints a Python traceback; every input file and every file of the user's put into
an output folder is still there, unchanged, and nothing was written inside an input; no temporary or partial
file is left. Read-only and unreadable cases run as the unprivileged user 65534 (setpriv) because root ignores
permissions; disk-full cases mount a small tmpfs; both are skipped when not run as root. The last line reads
`hostile: N cases, tracebacks T, data lost L, corrupt C, wrong exit E`, with the other problems, passes and skips
after it (corrupt: outputs that disagree with each other, e.g. frames that cameras.json does not list);
the exit status is 1 when any case failed any check.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import signal
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's insertnerf_cli, for the fixtures and the default launcher

import hostile_cases  # noqa: E402,F401  (registers its cases; bench/ is on sys.path when run as a script)
import hostile_finetune  # noqa: E402,F401
import hostile_inputs  # noqa: E402,F401
import hostile_models  # noqa: E402,F401
import hostile_races  # noqa: E402,F401
import hostile_scenefiles  # noqa: E402,F401
from hostile_kit import (CASES, NOBODY, STEP_TIMEOUT_S, Fixtures, Plan, Workspace, finish_insertnerf,  # noqa: E402
                         resume, run_insertnerf, start_insertnerf, wait_until_holding)

TRACEBACK = ("Traceback (most recent call last)", "Fatal Python error", "Check failure stack trace")
# Temporary names the tool uses (atomic.py, poses_io.py, synth/dataset.py) and common ones it might.
STRAY = re.compile(r"\.tmp|\.partial|\.old-|\.part$|~$")
# Lines that are progress, not messages: tqdm bars and the indented stage details of `poses`.
PROGRESS = re.compile(r"%\||\d+/\d+ \[|^\s+\S|^\[\d+/\d+\] ")
MAX_MESSAGE_LINES = 3
MAX_LINE_CHARS = 400


@dataclass
class Result:
    name: str
    command: str
    exits: list[str]
    traceback: bool = False
    lost: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    corrupt: list[str] = field(default_factory=list)
    wrong_exit: bool = False
    skipped: str | None = None
    seconds: float = 0.0

    @property
    def passed(self) -> bool:
        return not (self.traceback or self.lost or self.problems or self.corrupt or self.wrong_exit)


def launcher(installed: bool) -> list[str]:
    """The command line that starts `insertnerf`: this checkout's code by default."""
    if installed:
        return [shutil.which("insertnerf") or "insertnerf"]
    return [sys.executable, "-c", "import sys; sys.argv[0] = 'insertnerf'; from insertnerf_cli.cli.main import main; main()"]


def base_env(work: Path) -> dict[str, str]:
    home = work / "home"
    home.mkdir(exist_ok=True)
    home.chmod(0o777)
    env = dict(os.environ, OMP_NUM_THREADS="1", HOME=str(home), TMPDIR=str(home), XDG_CACHE_HOME=str(home),
               PYTHONPATH=str(ROOT), PYTHONDONTWRITEBYTECODE="1")
    env.pop("CUDA_VISIBLE_DEVICES", None)
    return env


def message_lines(text: str) -> list[str]:
    """The lines a person reads: the final state of each carriage-return line, progress bars left out."""
    lines = [line.split("\r")[-1] for line in text.split("\n")]
    return [line for line in lines if line.strip() and not PROGRESS.search(line)]


def exit_problem(expect: str, rc: int | None, out: str, err: str) -> tuple[bool, str | None]:
    """(wrong exit, problem with the message) of one step."""
    if rc is None:
        return True, f"no exit within {STEP_TIMEOUT_S} s"
    if expect == "ok":
        return rc != 0, None
    wrong = (expect == "fail" and not 1 <= rc <= 125) or (expect == "interrupt" and rc == 0)
    if expect == "any" or rc == 0:
        return wrong, None
    lines = message_lines(out + "\n" + err)
    if not lines:
        return wrong, "failed without a message"
    long = [line for line in lines if len(line) > MAX_LINE_CHARS]
    if len(lines) > MAX_MESSAGE_LINES or long:
        return wrong, f"long error output ({len(lines)} lines, last: {lines[-1][:80]!r})"
    return wrong, None


def digest(paths: list[Path], base: Path) -> dict[str, str]:
    """sha256 of every file under ``paths``, by path relative to ``base`` (root reads through any permission)."""
    files = {}
    for path in paths:
        for item in [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file()):
            files[str(item.relative_to(base))] = hashlib.sha256(item.read_bytes()).hexdigest()
    return files


def stray_files(folder: Path) -> list[str]:
    return [str(p.relative_to(folder)) for p in folder.rglob("*") if STRAY.search(p.name)]


def hand_to_nobody(folder: Path, locks: list[tuple[Path, int]]) -> None:
    for path in [folder, *folder.rglob("*")]:
        os.lchown(path, NOBODY, NOBODY)
    for path, mode in locks:
        path.chmod(mode)


def unlock(folder: Path) -> None:
    """Make a case folder readable and removable again after its permission games."""
    for path in [folder, *folder.rglob("*")]:
        if not path.is_symlink():
            path.chmod(path.stat().st_mode | 0o700)


def run_case(name: str, command: str, plan: Plan, case_dir: Path, env: dict[str, str], exe: list[str]) -> Result:
    result = Result(name, command, [])
    if any(step.nobody for step in plan.steps):
        hand_to_nobody(case_dir, plan.locks)
    guarded = digest(plan.inputs + plan.foreign, case_dir)
    inputs_before = set(digest(plan.inputs, case_dir))
    for step in plan.steps:
        if step.before is not None:
            step.before()
        first = None
        if step.alongside is not None:
            first = start_insertnerf(step.alongside, case_dir, env, exe)
            wait_until_holding(first, step.holds)
        try:
            _judge(result, step.expect, *run_insertnerf(step.args, case_dir, env, exe, step.nobody, step.signal))
        finally:
            if first is not None:
                resume(first)
                _judge(result, "ok", *finish_insertnerf(first))
    unlock(case_dir)
    after = digest(plan.inputs + plan.foreign, case_dir)
    result.lost = [path for path, sha in guarded.items() if after.get(path) != sha]
    written = set(digest(plan.inputs, case_dir)) - inputs_before
    if written:
        result.problems.append(f"wrote inside an input: {sorted(written)[:3]}")
    stray = stray_files(case_dir)
    if stray:
        result.problems.append(f"left temporary files: {stray[:3]}")
    extra = plan.check() if plan.check else None
    if extra:
        result.problems.append(extra)
    corrupt = plan.consistent() if plan.consistent else None
    if corrupt:
        result.corrupt.append(corrupt)
    return result


def _judge(result: Result, expect: str, rc: int | None, out: str, err: str) -> None:
    """Record one process's exit status, message and traceback in ``result``."""
    result.exits.append("timeout" if rc is None else str(rc))
    wrong, problem = exit_problem(expect, rc, out, err)
    result.wrong_exit |= wrong
    if problem:
        result.problems.append(problem)
    if any(mark in out + err for mark in TRACEBACK):
        result.traceback = True
        result.problems.append("traceback: " + _last_line(err))


def _last_line(text: str) -> str:
    """The exception line of a traceback (the last line naming an error), else the last line."""
    lines = [line for line in text.splitlines() if line.strip()]
    errors = [line for line in lines if re.match(r"[\w.]+(Error|Exception|Interrupt|Exit)\b", line)]
    return (errors or lines or [""])[-1][:160]


def report_line(r: Result) -> str:
    if r.skipped:
        return f"{r.name:<50} {r.command:<6} SKIPPED: {r.skipped}"
    verdict = "ok" if r.passed else "FAIL " + "; ".join(
        (["wrong exit"] if r.wrong_exit else []) + ([f"lost {len(r.lost)} files ({', '.join(r.lost[:2])})"] if r.lost else [])
        + [f"corrupt: {c}" for c in r.corrupt] + r.problems)[:300]
    return (f"{r.name:<50} {r.command:<6} {r.seconds:4.0f}s exit {','.join(r.exits):<9} traceback {'yes' if r.traceback else 'no ':<3} "
            f"data lost {'yes' if r.lost else 'no ':<3} {verdict}")


def summary(results: list[Result]) -> str:
    ran = [r for r in results if not r.skipped]
    commands = ("poses", "synth", "train", "render", "eval", "finetune")
    per_command = {c: sum(r.command == c for r in ran) for c in commands}
    return (f"hostile: {len(ran)} cases, tracebacks {sum(r.traceback for r in ran)}, "
            f"data lost {sum(bool(r.lost) for r in ran)}, corrupt {sum(bool(r.corrupt) for r in ran)}, "
            f"wrong exit {sum(r.wrong_exit for r in ran)}; "
            f"other problems {sum(bool(r.problems) and not r.traceback for r in ran)}, "
            f"passed {sum(r.passed for r in ran)}, skipped {len(results) - len(ran)}; per command {per_command}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", default="", help="run the cases whose name contains this text (or one of these, "
                        "comma-separated)")
    parser.add_argument("--keep", type=Path, help="work in this (new) folder and keep it")
    parser.add_argument("--installed", action="store_true", help="run `insertnerf` from PATH")
    parser.add_argument("--jobs", type=int, default=2, help="cases run at the same time")
    args = parser.parse_args()
    # A shell starts background jobs with SIGINT ignored, and children inherit that: Ctrl-C cases would test nothing.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    work = args.keep or Path(tempfile.mkdtemp(prefix="insertnerf-hostile-"))
    work.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(work / "cases", ignore_errors=True)  # an earlier run's cases (--keep)
    work.chmod(0o755)  # user 65534 must be able to walk to its case folders
    exe, env = launcher(args.installed), base_env(work)
    start = time.monotonic()
    results = []
    try:
        fixtures = Fixtures.build(work / "fixtures", env, exe)
        print(f"fixtures built in {time.monotonic() - start:.0f} s under {work}", flush=True)
        before = digest([fixtures.dir], fixtures.dir)
        chosen = [(name, command, make) for name, command, make in CASES
                  if any(part in name for part in args.only.split(","))]

        def one(entry: tuple) -> Result:
            name, command, make = entry
            return _one_case(name, command, make, Workspace(work / "cases" / name, fixtures), env, exe)

        with ThreadPoolExecutor(max_workers=args.jobs) as pool:  # cases are independent subprocesses
            for result in pool.map(one, chosen):
                results.append(result)
                print(report_line(result), flush=True)
        after = digest([fixtures.dir], fixtures.dir)
        if after != before:  # the checkpoint and config every case reads in place
            changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
            print(f"hostile: the fixtures changed during the run: {changed[:5]}")
            results.append(Result("fixtures_unchanged", "-", [], lost=changed))
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    print(f"wall time {time.monotonic() - start:.0f} s")
    print(summary(results))
    sys.exit(0 if all(r.passed for r in results) else 1)


def _one_case(name: str, command: str, make, ws, env: dict[str, str], exe: list[str]) -> Result:
    start = time.monotonic()
    try:
        plan = make(ws)
        if isinstance(plan, str):  # the case cannot run here (e.g. no tmpfs)
            return Result(name, command, [], skipped=plan)
        if os.geteuid() != 0 and any(step.nobody for step in plan.steps):
            return Result(name, command, [], skipped="needs root to run as user 65534")
        result = run_case(name, command, plan, ws.dir, env, exe)
        result.seconds = time.monotonic() - start
        return result
    finally:
        ws.close()


if __name__ == "__main__":
    main()
