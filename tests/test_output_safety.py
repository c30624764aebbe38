"""Output safety of every command: --overwrite removes only what insertnerf wrote, outputs never lie inside (or
hold) an input, and output paths that cannot be written are refused in one line before any work."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from click.testing import CliRunner
from cli_fixtures import make_checkpoint, make_scene, one_line_error, render_command, run
from test_train import cli_args, tiny_config, write_scene  # noqa: F401  (tiny_config is a fixture)

from insertnerf_cli.cli.main import cli
from insertnerf_cli.files.outdir import RECORD_NAME, OutputRecord
from insertnerf_cli.poses.folder import remove_stale_staging, staging_folder
from insertnerf_cli.synth import SynthOptions, build_dataset

pytestmark = pytest.mark.usefixtures("one_thread")
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def scene_and_checkpoint(tmp_path_factory):
    root = tmp_path_factory.mktemp("safety")
    return make_scene(root / "scene", {"train": 6, "test": 2}), make_checkpoint(root / "tiny.pt")


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------------------------------------ record
def test_a_record_never_reaches_outside_its_folder(tmp_path):
    outside = tmp_path / "precious"
    outside.mkdir()
    (outside / "a.txt").write_text("mine")
    out = tmp_path / "out"
    out.mkdir()
    (out / "ours.txt").write_text("ours")
    (out / "frames").symlink_to(outside, target_is_directory=True)  # a folder of ours replaced by a link
    (out / RECORD_NAME).write_text(json.dumps({"owners": {"render": [
        "../precious/a.txt", str(outside / "a.txt"), "frames/a.txt", "ours.txt"]}}))
    OutputRecord(out, "render").remove()
    assert (outside / "a.txt").read_text() == "mine" and not (out / "ours.txt").exists()


# ------------------------------------------------------------------------------------------------ render
def test_render_into_or_around_its_scene_is_refused_and_the_scene_is_untouched(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    before = snapshot(scene)
    one_line_error(render_command(scene, ckpt, scene, "--frames", 1, "--overwrite"), "is the input scene")
    one_line_error(render_command(scene, ckpt, scene / "views", "--frames", 1, "--overwrite"), "lies inside the input")
    one_line_error(render_command(scene, ckpt, scene.parent, "--frames", 1, "--overwrite"), "contains the input")
    # A symlink to the scene is the scene.
    (tmp_path / "link").symlink_to(scene, target_is_directory=True)
    one_line_error(render_command(scene, ckpt, tmp_path / "link", "--frames", 1, "--overwrite"), "is the input")
    assert snapshot(scene) == before


def test_render_of_photos_into_their_parent_is_refused(scene_and_checkpoint, tmp_path):
    _, ckpt = scene_and_checkpoint
    photos = tmp_path / "shoot" / "frames"
    shutil.copytree(scene_and_checkpoint[0] / "train", photos)
    before = snapshot(photos)
    one_line_error(render_command(photos, ckpt, tmp_path / "shoot", "--frames", 1, "--overwrite"), "contains the input")
    assert snapshot(photos) == before


@pytest.mark.slow
def test_render_overwrite_keeps_foreign_files(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / "views"
    assert render_command(scene, ckpt, out, "--frames", 3).exit_code == 0
    (out / "notes.txt").write_text("mine")
    (out / "frames" / "my_edit.png").write_bytes(b"mine")
    result = render_command(scene, ckpt, out, "--frames", 2, "--overwrite")
    assert result.exit_code == 0, result.output
    assert (out / "notes.txt").read_text() == "mine" and (out / "frames" / "my_edit.png").read_bytes() == b"mine"
    assert sorted(p.name for p in (out / "depth").iterdir()) == ["00000.png", "00001.png"]  # frame 2 was ours
    # A render of an older version (no record): only its exact file names go.
    (out / RECORD_NAME).unlink()
    (out / "depth" / "depth_notes.txt").write_text("mine")
    assert render_command(scene, ckpt, out, "--frames", 1, "--overwrite").exit_code == 0
    assert (out / "depth" / "depth_notes.txt").read_text() == "mine" and (out / "notes.txt").is_file()
    assert not (out / "frames" / "00001.png").exists()


@pytest.mark.slow
def test_refusal_names_the_setting_that_differs(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / "views"
    assert render_command(scene, ckpt, out, "--frames", 2).exit_code == 0
    one_line_error(render_command(scene, ckpt, out, "--frames", 3), "frames 2 -> 3", "--overwrite")
    one_line_error(render_command(scene, ckpt, out, "--frames", 2, "--views", 3), "views 2 -> 3")


# ------------------------------------------------------------------------------------------------ eval
def test_eval_outputs_inside_the_scene_or_onto_the_checkpoint_are_refused(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    before = snapshot(scene)
    common = ["eval", scene, "--checkpoint", ckpt, "--device", "cpu", "--resolution", 16, "--views", 2, "--overwrite"]
    one_line_error(run(*common, "--out", scene / "side"), "lies inside the input")
    one_line_error(run(*common, "--json", scene / "transforms_test.json"), "lies inside the input")
    one_line_error(run(*common, "--json", ckpt), "is the input")
    assert snapshot(scene) == before


@pytest.mark.slow
def test_eval_overwrite_keeps_foreign_files(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / "side"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "99999.png").write_bytes(b"old side-by-side of a version without records")
    result = run("eval", scene, "--checkpoint", ckpt, "--device", "cpu", "--resolution", 16, "--views", 2,
                 "--out", out, "--overwrite")
    assert result.exit_code == 0, result.output
    assert (out / "notes.txt").read_text() == "mine" and not (out / "99999.png").exists()
    ours = {p for p in OutputRecord(out, "eval").paths if p.split("/")[0] != "points"}  # the SfM points' cache
    assert ours == {p.name for p in out.glob("0*.png")} | {"report.html"}


# ------------------------------------------------------------------------------------------------ train
def trained_run(tmp_path: Path, out: Path, tiny_config: Path) -> tuple[Path, Path]:
    """A two-scene dataset under tmp_path and a 1-step run of it in ``out``: (dataset, out)."""
    data = tmp_path / "data"
    write_scene(data / "a", views=4, seed=0)
    write_scene(data / "b", views=4, seed=1)
    assert CliRunner().invoke(cli, cli_args(data, out, tiny_config, "--steps", "1")).exit_code == 0
    return data, out


@pytest.mark.slow
def test_train_overwrite_keeps_the_users_checkpoint_and_refuses_the_dataset(tiny_config, tmp_path):
    data, out = trained_run(tmp_path, tmp_path / "run", tiny_config)
    shutil.copy(out / "checkpoints" / "last.pt", out / "checkpoints" / "keep_step2.pt")
    (out / "notes.txt").write_text("mine")
    redo = CliRunner().invoke(cli, cli_args(data, out, tiny_config, "--steps", "1", "--overwrite"))
    assert redo.exit_code == 0, redo.output
    assert (out / "checkpoints" / "keep_step2.pt").is_file() and (out / "notes.txt").read_text() == "mine"
    # The same for a run folder of a version without records.
    (out / RECORD_NAME).unlink()
    redo = CliRunner().invoke(cli, cli_args(data, out, tiny_config, "--steps", "1", "--overwrite"))
    assert redo.exit_code == 0, redo.output
    assert (out / "checkpoints" / "keep_step2.pt").is_file()
    before = snapshot(data)
    one_line_error(CliRunner().invoke(cli, cli_args(data, data / "a" / "run", tiny_config, "--overwrite")),
                   "lies inside the input dataset")
    one_line_error(CliRunner().invoke(cli, cli_args(data, tmp_path, tiny_config, "--overwrite")),
                   "contains the input dataset")
    assert snapshot(data) == before


@pytest.mark.slow
def test_render_into_a_run_folder_and_train_over_it_leave_each_others_files(scene_and_checkpoint, tiny_config,
                                                                             tmp_path):
    scene, ckpt = scene_and_checkpoint
    data, out = trained_run(tmp_path, tmp_path / "run", tiny_config)
    one_line_error(render_command(scene, ckpt, out, "--frames", 1), "already holds other files", "--overwrite")
    for _ in range(2):  # the second --overwrite replaces the first render, and only it
        assert render_command(scene, ckpt, out, "--frames", 1, "--overwrite").exit_code == 0
        assert (out / "checkpoints" / "last.pt").is_file() and (out / "metrics.jsonl").is_file()
    assert CliRunner().invoke(cli, cli_args(data, out, tiny_config, "--steps", "1", "--overwrite")).exit_code == 0
    assert (out / "frames" / "00000.png").is_file() and (out / "video.mp4").is_file()


@pytest.mark.slow
def test_train_killed_before_its_first_checkpoint_starts_afresh(tiny_config, tmp_path):
    data, out = trained_run(tmp_path, tmp_path / "run", tiny_config)
    for ckpt in (out / "checkpoints").glob("*.pt"):  # what a kill -9 before the first checkpoint leaves
        ckpt.unlink()
    one_line_error(CliRunner().invoke(cli, cli_args(data, out, tiny_config, "--resume")), "nothing to resume",
                   "without --resume")
    again = CliRunner().invoke(cli, cli_args(data, out, tiny_config, "--steps", "1"))
    assert again.exit_code == 0, again.output
    assert "starting it afresh" in again.output and (out / "checkpoints" / "last.pt").is_file()


# ------------------------------------------------------------------------------------------------ synth
@pytest.mark.slow
def test_synth_overwrite_keeps_foreign_files(tmp_path):
    out = tmp_path / "data"
    options = SynthOptions(scenes=1, views=3, test_views=1, resolution=16, layout="object")
    build_dataset(out, options, progress=False)
    (out / "notes.txt").write_text("mine")
    (out / "scene_00000" / "my_labels.json").write_text("{}")
    (out / "scene_99999").mkdir()  # a folder named like ours that synth did not write
    (out / "scene_99999" / "x.txt").write_text("mine")
    build_dataset(out, SynthOptions(scenes=1, views=3, test_views=1, resolution=16, layout="object", seed=1),
                  overwrite=True, progress=False)
    assert (out / "notes.txt").read_text() == "mine" and (out / "scene_99999" / "x.txt").read_text() == "mine"
    assert (out / "scene_00000" / "my_labels.json").is_file()  # kept inside our folder, beside the new files
    assert json.loads((out / "manifest.json").read_text())["options"]["seed"] == 1
    assert json.loads((out / "scene_00000" / "scene.json").read_text())["spec"]["seed"] == 1  # rendered anew


# ------------------------------------------------------------------------------------------------ poses
def test_poses_overwrite_keeps_foreign_files_and_clears_dead_partials(tmp_path):
    out = tmp_path / "scene"

    def build(text: str) -> None:
        with staging_folder(out) as tmp:
            (tmp / "images").mkdir()
            (tmp / "images" / "a.png").write_text(text)
            (tmp / "transforms.json").write_text(text)

    build("first")
    (out / "notes.txt").write_text("mine")
    (out / "images" / "my_crop.png").write_text("mine")
    build("second")
    assert (out / "transforms.json").read_text() == "second" and (out / "images" / "a.png").read_text() == "second"
    assert (out / "notes.txt").read_text() == "mine" and (out / "images" / "my_crop.png").read_text() == "mine"
    # A kill -9 leaves .scene.partial-<pid>-*: the next run removes it once that process is gone.
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / f".scene.partial-{dead.pid}-x" / "colmap").mkdir(parents=True)
    (tmp_path / f".scene.partial-{os.getpid()}-y").mkdir()  # a live run's: kept
    remove_stale_staging(out)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == [f".scene.partial-{os.getpid()}-y"]


def test_poses_output_around_the_photos_is_refused(tmp_path):
    (tmp_path / "photos").mkdir()
    one_line_error(run("poses", tmp_path / "photos", "--out", tmp_path / "photos" / "scene"), "lies inside")


# ------------------------------------------------------------------------------------------------ paths
def test_output_whose_parent_is_a_file_is_one_line_for_every_command(scene_and_checkpoint, tiny_config, tmp_path):
    scene, ckpt = scene_and_checkpoint
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    model = ["--checkpoint", ckpt, "--device", "cpu", "--resolution", 16]
    cases = [
        ("render", scene, "--out", blocker / "views", *model),
        ("eval", scene, "--out", blocker / "side", *model),
        ("eval", scene, "--json", blocker / "scores.json", *model),
        ("poses", scene / "train", "--out", blocker / "scene"),
        ("synth", blocker / "data", "--scenes", 1),
    ]
    for args in cases:
        one_line_error(run(*args), "is a file")
    one_line_error(CliRunner().invoke(cli, cli_args(scene.parent, blocker / "run", tiny_config)), "is a file")


_AS_NOBODY = """
import json, sys
from click.testing import CliRunner
from insertnerf_cli.cli.main import cli
scene, ckpt, ro = sys.argv[1:4]
out = {}
for name, args in {"eval": ["eval", scene, "--json", ro + "/scores.json"],
                   "render": ["render", scene, "--out", ro + "/views"]}.items():
    r = CliRunner().invoke(cli, args + ["--checkpoint", ckpt, "--device", "cpu", "--resolution", "16"])
    out[name] = [r.exit_code, r.output]
print(json.dumps(out))
"""


@pytest.mark.slow
def test_read_only_output_folder_is_refused_before_any_work(scene_and_checkpoint):
    """As an unprivileged user (root ignores permissions): eval --json and render --out into a folder that user
    cannot write are one line, before the evaluation or render runs."""
    if os.geteuid() == 0 and shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: cannot drop the privileges that ignore permissions")
    base = Path(tempfile.mkdtemp(prefix="insertnerf-ro-"))
    try:
        os.chmod(base, 0o755)
        scene = shutil.copytree(scene_and_checkpoint[0], base / "scene")
        ckpt = shutil.copy(scene_and_checkpoint[1], base / "tiny.pt")
        (base / "ro").mkdir()
        os.chmod(base / "ro", 0o555)  # and owned by root: the unprivileged user cannot write either way
        prefix = (["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", "--inh-caps=-all"]
                  if os.geteuid() == 0 else [])
        env = {**os.environ, "PYTHONPATH": str(REPO), "HOME": str(base), "OMP_NUM_THREADS": "1"}
        probe = subprocess.run([*prefix, sys.executable, "-c", "import click, torch, insertnerf_cli"],
                               capture_output=True, text=True, env=env, timeout=120)
        if probe.returncode != 0:  # e.g. a venv inside a 0700 temporary folder: nothing to test as that user
            pytest.skip("the unprivileged user cannot import this Python's packages: "
                        + (probe.stderr.strip().splitlines() or ["?"])[-1])
        done = subprocess.run([*prefix, sys.executable, "-c", _AS_NOBODY, str(scene), str(ckpt), str(base / "ro")],
                              capture_output=True, text=True, env=env, timeout=120)
        assert done.returncode == 0, done.stderr[-2000:]
        for name, (code, output) in json.loads(done.stdout.splitlines()[-1]).items():
            assert code == 1 and "no permission to write" in output and "Traceback" not in output, (name, output)
            assert "evaluating" not in output and "rendering" not in output
        assert list((base / "ro").iterdir()) == []
    finally:
        os.chmod(base / "ro", 0o755)
        shutil.rmtree(base, ignore_errors=True)
