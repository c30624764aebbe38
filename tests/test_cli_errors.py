"""The command boundary: bad option values, OS errors (permissions, disk full) and Ctrl-C at start-up each end
in one line and a non-zero exit, never a traceback. Permission cases run in a child process without the
capabilities that let root read anything; Ctrl-C is a real SIGINT to a real `insertnerf` process."""
from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from insertnerf_cli.cli.main import cli
from insertnerf_cli.cli.commands.common import user_errors
from insertnerf_cli.config import ModelConfig, config_to_json
from insertnerf_cli.errors import os_error_message
from cli_fixtures import one_line_error
from scene_fixtures import known_scene, write_blender, write_nerfstudio

pytestmark = pytest.mark.usefixtures("one_thread")
REPO = Path(__file__).resolve().parents[1]
MAIN = "from insertnerf_cli.cli.main import main; main()"


@pytest.fixture()
def scene(tmp_path: Path) -> Path:
    return write_nerfstudio(tmp_path / "scene", known_scene())


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "0", "-5"])
def test_render_fps_must_be_finite_and_positive(tmp_path: Path, scene: Path, value: str) -> None:
    out = tmp_path / "out"
    result = CliRunner().invoke(cli, ["render", str(scene), "--out", str(out), "--fps", value])
    assert "--fps" in one_line_error(result, exit_code=2)  # refused while parsing: before any frame is rendered
    assert not out.exists()


@pytest.mark.parametrize("flags, expected", [
    (["--lr", "nan"], "lr must be a finite number"),
    (["--lr", "-1"], "learning rates must be positive"),
    (["--minutes", "nan"], "minutes must be a finite number or null"),
    (["--minutes", "0"], "--minutes must be positive"),
    (["--steps", "0"], "steps=0"),
    (["--seed", "-1"], "--seed must be between 0 and"),
    (["--seed", str(2 ** 64)], "--seed must be between 0 and"),
    (["--views", "0"], "num_views=0"),
])
def test_bad_train_options_are_one_line(tmp_path: Path, scene: Path, flags: list[str], expected: str) -> None:
    result = CliRunner().invoke(cli, ["train", str(scene), "--out", str(tmp_path / "run"), "--device", "cpu", *flags])
    assert expected in one_line_error(result)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("change, expected", [
    ({"nerf_width": -32}, "nerf_width=-32: must be positive"),
    ({"nerf_width": 0}, "nerf_width=0"),
    ({"encoder_widths": [8, 8, -8, 8]}, "encoder_widths"),
    ({"nerf_width": "wide"}, "nerf_width must be a whole number"),
    ({"coord_scale": float("nan")}, "coord_scale must be a finite number"),
    ({"conditioning": "film"}, "conditioning must be one of 'hyper', 'concat'"),
    ({"separate_fine_head": 1}, "separate_fine_head must be true or false"),
])
def test_bad_model_config_is_one_line_naming_the_file(tmp_path: Path, scene: Path, change, expected: str) -> None:
    path = tmp_path / "model.json"
    path.write_text(json.dumps({**config_to_json(ModelConfig()), **change}))
    result = CliRunner().invoke(cli, ["train", str(scene), "--out", str(tmp_path / "run"), "--device", "cpu",
                                      "--model-config", str(path)])
    line = one_line_error(result)
    assert expected in line and str(path) in line


def real_os_errors(tmp_path: Path) -> list[tuple[OSError, str]]:
    """OSErrors raised by real file operations, with the words their one line must hold."""
    (tmp_path / "file").write_text("x")
    raised = []
    for attempt, words in [(lambda: open(tmp_path), "is a folder where a file was expected"),
                           (lambda: open(tmp_path / "file" / "child", "w"), "a part of the path is a file"),
                           (lambda: open(tmp_path / "missing"), "does not exist"),
                           (lambda: os.mkdir(tmp_path), "already exists")]:
        with pytest.raises(OSError) as info:
            attempt()
        raised.append((info.value, words))
    return raised


def test_os_error_message_names_the_path_and_what_to_do(tmp_path: Path) -> None:
    for err, words in real_os_errors(tmp_path):
        line = os_error_message(err)
        assert words in line and str(tmp_path) in line and "\n" not in line
    read_only = OSError(errno.EROFS, os.strerror(errno.EROFS), "/mnt/cdrom/out")
    assert os_error_message(read_only).startswith("read-only file system: /mnt/cdrom/out; choose")
    assert "check its permissions" in os_error_message(PermissionError(errno.EACCES, "Permission denied", "/x"))


@click.command()
@click.argument("path")
@user_errors
def write_a_lot(path: str) -> None:
    with open(path, "wb") as f:
        f.write(b"\0" * (1 << 20))


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full (Linux) for a real ENOSPC")
def test_disk_full_at_the_boundary_is_one_line() -> None:
    line = one_line_error(CliRunner().invoke(write_a_lot, ["/dev/full"]))
    assert line.startswith("Error: disk full") and "free some space" in line


def test_a_bug_keeps_its_traceback() -> None:
    @click.command()
    @user_errors
    def buggy() -> None:
        raise ZeroDivisionError("a real bug")

    result = CliRunner().invoke(buggy, [])
    assert isinstance(result.exception, ZeroDivisionError)  # not turned into a tidy but misleading line


# ---------------------------------------------------------------- permissions, in a child without privileges

CHILD = r"""
import json, sys
from pathlib import Path
from click.testing import CliRunner
from insertnerf_cli.cli.main import cli
from insertnerf_cli.training.data import find_scenes

cases, probe = json.loads(sys.argv[1]), Path(sys.argv[2])
try:
    probe.read_bytes()
    print(json.dumps({"skip": "a mode-000 file is still readable: privileges could not be dropped"}))
    sys.exit(0)
except PermissionError:
    pass
results = {}
for name, args in cases.items():
    if args[0] == "find_scenes":
        said = []
        found = [s.name for s in find_scenes(Path(args[1]), 16, said.append, show_progress=False)]
        results[name] = {"found": found, "said": said}
        continue
    r = CliRunner().invoke(cli, args)
    results[name] = {"code": r.exit_code, "output": r.output, "system_exit": isinstance(r.exception, SystemExit)}
print(json.dumps(results))
"""


def unprivileged() -> list[str]:
    """The command prefix that runs a child without the capabilities that let root ignore permissions."""
    if os.geteuid() != 0:
        return []
    if shutil.which("setpriv") is None:
        pytest.skip("running as root and setpriv is missing: cannot test permissions")
    return ["setpriv", "--bounding-set=-all", "--inh-caps=-all"]


@pytest.mark.slow
def test_unreadable_inputs_are_one_line_and_skipped_in_datasets(tmp_path: Path) -> None:
    known = known_scene(n=8)
    no_train = write_blender(tmp_path / "no_train", known)
    (no_train / "train").chmod(0)
    no_image = write_nerfstudio(tmp_path / "no_image", known)
    (no_image / "images" / "view_002.png").chmod(0)
    no_json = write_nerfstudio(tmp_path / "no_json", known)
    (no_json / "transforms.json").chmod(0)
    photos = tmp_path / "photos"
    photos.mkdir(mode=0)
    data = tmp_path / "data"
    for name in ("good", "locked", "locked_train"):
        write_blender(data / name, known)
    (data / "locked_train" / "train").chmod(0)
    (data / "locked").chmod(0)
    read_only = tmp_path / "read_only"
    read_only.mkdir(mode=0o555)
    render = ["render", "--device", "cpu", "--frames", "1", "--resolution", "8", "--out"]
    cases = {"no_train": [*render, str(tmp_path / "o1"), str(no_train)],
             "no_image": [*render, str(tmp_path / "o2"), str(no_image)],
             "no_json": [*render, str(tmp_path / "o3"), str(no_json)],
             "photos": ["poses", str(photos), "--out", str(tmp_path / "posed")],
             "out_read_only": [*render, str(read_only / "out"), str(write_nerfstudio(tmp_path / "ok", known))],
             "dataset": ["find_scenes", str(data)]}
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1")
    try:
        child = subprocess.run([*unprivileged(), sys.executable, "-c", CHILD, json.dumps(cases),
                                str(no_json / "transforms.json")], capture_output=True, text=True, env=env,
                               timeout=300, cwd=tmp_path)
    finally:
        for path in (no_train / "train", data / "locked_train" / "train", data / "locked", photos, read_only):
            path.chmod(0o755)  # let pytest clean up
    assert child.returncode == 0, child.stderr
    results = json.loads(child.stdout.strip().splitlines()[-1])
    if "skip" in results:
        pytest.skip(results["skip"])
    for name, expected in [("no_train", "no_train/train"), ("no_image", "view_002.png"),
                           ("no_json", "transforms.json"), ("out_read_only", "read_only"), ("photos", "photos")]:
        got = results[name]
        lines = [line for line in got["output"].splitlines() if line.startswith("Error")]
        assert got["system_exit"] and "Traceback" not in got["output"] and len(lines) == 1, (name, got)
        assert expected in lines[0], (name, got)
        if name == "photos":  # click's own check of IMAGES_DIR: a usage error
            assert got["code"] == 2 and "is not readable" in lines[0]
        elif name == "out_read_only":  # refused by the output check before any work (outdir.check_writable)
            assert got["code"] == 1 and "no permission to write" in lines[0] and "permissions" in lines[0]
        else:
            assert got["code"] == 1 and "permission denied" in lines[0] and "check its permissions" in lines[0]
    assert results["dataset"]["found"] == ["good"]
    said = results["dataset"]["said"]
    assert len(said) == 2 and said[0].startswith("skipping locked: ") and "permission denied" in said[0]
    assert said[1].startswith("skipping locked_train: ") and "locked_train/train" in said[1]


# ---------------------------------------------------------------- Ctrl-C during start-up

def wait_for_torch(pid: int, timeout_s: float = 60.0) -> bool:
    """True once the process has started loading torch's libraries (it is then deep in its imports)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if "libtorch" in Path(f"/proc/{pid}/maps").read_text():
                return True
        except OSError:
            return False
        time.sleep(0.005)
    return False


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs /proc to see when torch starts loading")
def test_ctrl_c_while_torch_loads_is_one_line(tmp_path: Path, scene: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1")
    args = [sys.executable, "-c", MAIN, "render", str(scene), "--out", str(tmp_path / "out"), "--device", "cpu",
            "--frames", "1", "--resolution", "8"]
    child = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                             cwd=tmp_path)  # not the repo: `-c` puts the working folder first on sys.path
    try:
        assert wait_for_torch(child.pid), "the child never loaded torch"
        child.send_signal(signal.SIGINT)
        _, err = child.communicate(timeout=120)
    finally:
        child.kill()
    assert child.returncode == 130, err
    assert "Traceback" not in err and "terminate called" not in err
    assert err.strip().splitlines()[-1].startswith("Interrupted")
