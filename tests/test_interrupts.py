"""Long stages stop on Ctrl-C within 2 s with exit 130 and leave nothing half-made under the final name: `poses`
at each of its stages, and render's triangulation of SfM points (real subprocesses, real signals)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import cv2
import pytest
from cli_fixtures import make_checkpoint

import textured_scenes
from insertnerf_cli.scenes.writers import write_nerfstudio_transforms

pytestmark = pytest.mark.slow
MAIN = "import sys; sys.argv[0] = 'insertnerf'; from insertnerf_cli.cli.main import main; main()"
LIMIT_S = 2.0


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    """(14 photos of the textured room, a posed scene of them without points)."""
    truth = textured_scenes.render_scene(views=14, size=200, arc_deg=100.0)
    root = tmp_path_factory.mktemp("interrupts")
    (root / "photos").mkdir()
    (root / "posed" / "images").mkdir(parents=True)
    names = [f"view_{i:02d}.png" for i in range(len(truth.images))]
    for name, image in zip(names, truth.images):
        cv2.imwrite(str(root / "photos" / name), image[..., ::-1])
        cv2.imwrite(str(root / "posed" / "images" / name), image[..., ::-1])
    write_nerfstudio_transforms(root / "posed" / "transforms.json", truth.cameras, [f"images/{n}" for n in names],
                                near=0.5, far=8.0)
    return root / "photos", root / "posed"


def _ctrl_c_as_in_a_terminal() -> None:
    """SIGINT back to its default in the child: a suite started in the background by a non-interactive shell
    inherits it ignored, and Python then never turns it into KeyboardInterrupt."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _run_until(args: list[str], marker: str, delay: float, signum: int) -> tuple[int, float, str]:
    """(exit code, seconds from the signal to the exit, stderr) of `insertnerf ARGS` signalled ``delay`` s after
    ``marker`` shows on its stderr."""
    proc = subprocess.Popen([sys.executable, "-c", MAIN, *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"}, preexec_fn=_ctrl_c_as_in_a_terminal)
    seen = b""
    while marker.encode() not in seen:  # read as it comes, not by lines: a stage's line ends only when it is done
        data = os.read(proc.stderr.fileno(), 4096)
        assert data, f"the run ended before {marker!r}: {seen.decode(errors='replace')}"
        seen += data
    time.sleep(delay)
    sent = time.perf_counter()
    proc.send_signal(signum)
    try:
        code = proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    return code, time.perf_counter() - sent, (seen + proc.stderr.read()).decode(errors="replace")


@pytest.mark.parametrize("marker, delay", [("[2/6]", 0.2), ("[3/6]", 0.1), ("[4/6]", 0.1)],
                         ids=["features", "matching", "mapping"])
def test_ctrl_c_in_each_stage_of_poses_exits_130_at_once_and_leaves_no_scene(photos, tmp_path, marker, delay):
    out = tmp_path / "scene"
    code, took, err = _run_until(["poses", str(photos[0]), "--out", str(out)], marker, delay, signal.SIGINT)
    assert code == 130 and took < LIMIT_S, (code, took, err[-500:])
    assert "Traceback" not in err and not out.exists()


@pytest.mark.parametrize("marker", ["[2/6]", "[3/6]", "[4/6]"])
def test_kill_9_in_poses_leaves_no_folder_under_the_final_name(photos, tmp_path, marker):
    out = tmp_path / "scene"
    code, _, _ = _run_until(["poses", str(photos[0]), "--out", str(out)], marker, 0.1, signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert not out.exists() or (out / "transforms.json").is_file()  # none, or a whole scene


def test_ctrl_c_during_renders_triangulation_exits_130_at_once(photos, tmp_path):
    ckpt = make_checkpoint(tmp_path / "tiny.pt")
    out = tmp_path / "views"
    args = ["render", str(photos[1]), "--out", str(out), "--checkpoint", str(ckpt), "--device", "cpu",
            "--frames", "1", "--resolution", "32"]
    code, took, err = _run_until(args, "triangulating", 0.3, signal.SIGINT)
    assert code == 130 and took < LIMIT_S, (code, took, err[-500:])
    assert "Traceback" not in err and "image pairs" not in err  # stopped inside the triangulation, not after it


def test_ctrl_c_while_a_finished_command_shuts_down_prints_no_traceback():
    """A Ctrl-C that lands after the command's body (here from an exit handler, as the interpreter shuts down)
    leaves the command's exit code and prints nothing."""
    late = ("import atexit, os, signal, time; "
            "atexit.register(lambda: (os.kill(os.getpid(), signal.SIGINT), time.sleep(0.2))); ")
    done = subprocess.run([sys.executable, "-c", late + MAIN, "--version"], capture_output=True, text=True,
                          timeout=60, preexec_fn=_ctrl_c_as_in_a_terminal)
    assert done.returncode == 0, done.stderr
    assert "insertnerf" in done.stdout
    assert "Traceback" not in done.stderr and "KeyboardInterrupt" not in done.stderr, done.stderr
