"""The pieces bench/hostile.py and its case files share: a Step and a Plan, running `insertnerf` as a subprocess
(optionally as user 65534, optionally signalled mid-run), the fixtures built once, each case's Workspace, and the
case registry."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import cv2

NOBODY = 65534  # the unprivileged user of the permission cases (root ignores file modes)
STEP_TIMEOUT_S = 300
CASES: list[tuple[str, str, Callable]] = []  # (name, command, make(workspace) -> Plan | skip reason)
KILL, INT = signal.SIGKILL, signal.SIGINT
TINY_MODEL = dict(encoder_widths=[4, 4, 4, 4], feature_dims=[4, 4, 4], backbone_decoder_width=4, aggregate_hidden=4,
                  nerf_width=8, nerf_layers=2, appearance_width=8, z_branches=1, film_hidden=8, samples_coarse=8,
                  samples_fine=8, pe_freqs_pos=2, pe_freqs_dir=1, num_views=2)


@dataclass(frozen=True)
class Step:
    """One `insertnerf` run. expect: "ok" (exit 0), "fail" (exit 1-125, a short message), "interrupt" (a signal
    was sent: exit non-zero, a short message), "any" (no exit expectation)."""

    args: list[str]
    expect: str = "fail"
    nobody: bool = False
    signal: tuple[int, str, float] | None = None  # (signal, text on stderr to wait for ("" none), then delay s)
    before: Callable[[], None] | None = None  # runs just before the step (e.g. fill a disk)
    # A first writer run alongside: started before this step, frozen (SIGSTOP) once the lock file ``holds`` names
    # it, so that this step meets it, then let go (SIGCONT); it must exit 0 without a traceback.
    alongside: list[str] | None = None
    holds: Path | None = None


@dataclass(frozen=True)
class Plan:
    """A case: its steps, the inputs (nothing in them may change, vanish or appear), the user's foreign files
    (nothing may change or vanish), permissions applied after the case folder is handed to user 65534, and an
    extra check that returns a problem or None."""

    steps: list[Step]
    inputs: list[Path] = field(default_factory=list)
    foreign: list[Path] = field(default_factory=list)
    locks: list[tuple[Path, int]] = field(default_factory=list)
    check: Callable[[], str | None] | None = None
    consistent: Callable[[], str | None] | None = None  # the outputs agree with each other (else: corrupt)


@dataclass
class Running:
    """A started `insertnerf` process and the threads draining its output."""

    proc: subprocess.Popen
    chunks: dict[str, list[bytes]]
    readers: list[threading.Thread]


def start_insertnerf(args: list[str], cwd: Path, env: dict[str, str], exe: list[str],
                     nobody: bool = False) -> Running:
    drop = ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups", "--inh-caps=-all"]
    proc = subprocess.Popen([*(drop if nobody else []), *exe, *args], cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    chunks: dict[str, list[bytes]] = {"out": [], "err": []}
    readers = [threading.Thread(target=_drain, args=(pipe, chunks[key]), daemon=True)
               for key, pipe in (("out", proc.stdout), ("err", proc.stderr))]
    for reader in readers:
        reader.start()
    return Running(proc, chunks, readers)


def wait_until_holding(run: Running, lock: Path) -> None:
    """Freeze ``run`` (its whole process group) once ``lock`` names it, or return when it ended first."""
    deadline = time.monotonic() + STEP_TIMEOUT_S
    while run.proc.poll() is None and time.monotonic() < deadline:
        try:
            if lock.read_text().split()[:1] == [str(run.proc.pid)]:
                os.killpg(run.proc.pid, signal.SIGSTOP)
                return
        except (OSError, IndexError):
            pass
        time.sleep(0.01)


def resume(run: Running) -> None:
    if run.proc.poll() is None:
        os.killpg(run.proc.pid, signal.SIGCONT)


def run_insertnerf(args: list[str], cwd: Path, env: dict[str, str], exe: list[str], nobody: bool = False,
                   sig: tuple[int, str, float] | None = None) -> tuple[int | None, str, str]:
    """Run one step; with ``sig`` send that signal to its process group once ``marker`` shows on stderr."""
    run = start_insertnerf(args, cwd, env, exe, nobody)
    if sig is not None:
        _signal_when(run.proc, run.chunks["err"], *sig)
    return finish_insertnerf(run)


def finish_insertnerf(run: Running) -> tuple[int | None, str, str]:
    """Wait for ``run`` (killed after STEP_TIMEOUT_S): exit status (None on timeout), stdout, stderr."""
    proc, chunks, readers = run.proc, run.chunks, run.readers
    try:
        rc: int | None = proc.wait(timeout=STEP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        rc = None
    for reader in readers:
        reader.join()
    return rc, b"".join(chunks["out"]).decode(errors="replace"), b"".join(chunks["err"]).decode(errors="replace")


def _drain(pipe, sink: list[bytes]) -> None:
    for chunk in iter(lambda: pipe.read1(4096), b""):
        sink.append(chunk)


def _signal_when(proc: subprocess.Popen, err: list[bytes], signum: int, marker: str, delay: float) -> None:
    deadline = time.monotonic() + STEP_TIMEOUT_S
    while marker and marker.encode() not in b"".join(err) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(delay)
    if proc.poll() is None:
        os.killpg(proc.pid, signum)


def case(make: Callable) -> Callable:
    """Register a case; its command is the first word of its name."""
    name = make.__name__.removeprefix("case_")
    CASES.append((name, name.split("_")[0], make))
    return make


@dataclass(frozen=True)
class Fixtures:
    """Made once: a 4-scene synth dataset (8 views, 32 px), a tiny model config and a 2-step run of it, a render of
    one scene with that checkpoint, 16 photos of a ray-cast room (240 px) and their posed scene. Cases copy what
    they may damage; the checkpoint and the config are used in place (hostile.py checks they stay unchanged)."""

    dir: Path
    data: Path
    tiny: Path
    run: Path
    room: Path
    room_scene: Path
    render_out: Path

    @property
    def ckpt(self) -> Path:
        return self.run / "checkpoints" / "last.pt"

    @staticmethod
    def build(folder: Path, env: dict[str, str], exe: list[str]) -> "Fixtures":
        """Make the fixtures in ``folder``, or reuse them when a finished earlier build is there (--keep)."""
        from poses_accuracy import room_truth

        fx = Fixtures(folder, folder / "data", folder / "tiny.json", folder / "run", folder / "room" / "images",
                      folder / "room_scene", folder / "render_out")
        if (folder / "built").is_file():
            return fx
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        fx.tiny.write_text(json.dumps(TINY_MODEL))
        for args in (synth_args(fx.data, "--scenes", "4", "--views", "8", "--resolution", "32"),
                     train_args(fx, fx.data, fx.run),
                     render_args(fx, fx.data / "scene_00000", fx.render_out)):
            _must_pass(args, folder, env, exe)
        room_truth(folder / "room", 16, 240)
        _must_pass(["poses", str(fx.room), "--out", str(fx.room_scene)], folder, env, exe)
        for path in [folder, *folder.rglob("*")]:
            path.chmod(0o755 if path.is_dir() else 0o644)  # readable by user 65534 too
        (folder / "built").write_text("")
        return fx


def _must_pass(args: list[str], cwd: Path, env: dict[str, str], exe: list[str]) -> None:
    rc, out, err = run_insertnerf(args, cwd, env, exe)
    if rc != 0:
        raise SystemExit(f"hostile: fixture step `insertnerf {' '.join(args)}` failed ({rc}):\n{out}\n{err}")


@dataclass
class Workspace:
    """One case's folder and helpers to fill it; close() unmounts what tmpfs() mounted."""

    dir: Path
    fx: Fixtures
    mounts: list[Path] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.dir.mkdir(parents=True)

    def scene(self, name: str = "scene", index: int = 0) -> Path:
        return Path(shutil.copytree(self.fx.data / f"scene_{index:05d}", self.dir / name))

    def dataset(self, name: str = "data") -> Path:
        return Path(shutil.copytree(self.fx.data, self.dir / name))

    def photos(self, name: str = "photos", count: int = 16) -> Path:
        folder = self.dir / name
        folder.mkdir(parents=True)
        for path in sorted(self.fx.room.iterdir())[:count]:
            shutil.copy(path, folder / path.name)
        return folder

    def file(self, rel: str, text: str = "the user's own file\n") -> Path:
        path = self.dir / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        return path

    def tmpfs(self, rel: str, kilobytes: int) -> Path | None:
        path = self.dir / rel
        path.mkdir(parents=True)
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={kilobytes}k", "tmpfs", str(path)],
                              capture_output=True)
        if done.returncode != 0:
            return None
        self.mounts.append(path)
        return path

    def close(self) -> None:
        for path in self.mounts:
            subprocess.run(["umount", "-l", str(path)], capture_output=True)


def edit_transforms(scene: Path, change: Callable[[dict], None], split: str = "train") -> Path:
    path = scene / f"transforms_{split}.json"
    meta = json.loads(path.read_text())
    change(meta)
    path.write_text(json.dumps(meta))
    return path


def fill_disk(folder: Path, leave_kb: int) -> Callable[[], None]:
    """A `before` step: fill the file system of ``folder`` until about ``leave_kb`` KiB remain."""
    def fill() -> None:
        free = shutil.disk_usage(folder).free - leave_kb * 1024
        (folder / "filler.bin").write_bytes(b"\0" * max(free, 0))
    return fill


def render_args(fx: Fixtures, scene: Path, out: Path, *extra: str) -> list[str]:
    return ["render", str(scene), "--out", str(out), "--frames", "2", "--resolution", "32",
            "--checkpoint", str(fx.ckpt), "--device", "cpu", *extra]


def eval_args(fx: Fixtures, scene: Path, *extra: str) -> list[str]:
    return ["eval", str(scene), "--max-views", "1", "--resolution", "32", "--checkpoint", str(fx.ckpt),
            "--device", "cpu", *extra]


def train_args(fx: Fixtures, data: Path, out: Path, *extra: str) -> list[str]:
    return ["train", str(data), "--out", str(out), "--model-config", str(fx.tiny), "--steps", "2", "--rays", "32",
            "--resolution", "32", "--val-every", "1000", "--ckpt-every", "1", "--log-every", "1", "--device", "cpu",
            *extra]


def synth_args(out: Path, *extra: str) -> list[str]:
    return ["synth", str(out), "--scenes", "1", "--views", "4", "--resolution", "16", "--layout", "object",
            "--workers", "1", "--square", *extra]


def poses_args(images: Path, out: Path, *extra: str) -> list[str]:
    return ["poses", str(images), "--out", str(out), *extra]


def frames_decodable(out: Path) -> str | None:
    """Every frame and depth map under its final name decodes (no zero-byte or truncated file)."""
    bad = [p.name for kind in ("frames", "depth", "depth_vis") for p in sorted((out / kind).glob("*.png"))
           if cv2.imread(str(p), cv2.IMREAD_UNCHANGED) is None]
    return f"undecodable outputs under final names: {bad[:4]}" if bad else None
