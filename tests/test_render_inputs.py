"""What `render` renders from: a COLMAP project whose images/ holds photos without poses is posed like a plain
photo folder, instead of being refused."""
from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest
from cli_fixtures import make_checkpoint, make_scene, run

from insertnerf_cli.pipelines.inputs import unposed_photos

pytestmark = pytest.mark.usefixtures("one_thread")


def _photos(folder, count=3):
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(count):
        iio.imwrite(folder / f"{i}.png", rng.integers(0, 255, (64, 64, 3), dtype=np.uint8))


def test_a_project_folder_with_images_is_photos_and_a_scene_is_not(tmp_path):
    _photos(tmp_path / "project" / "images")
    (tmp_path / "project" / "database.db").write_bytes(b"")  # what COLMAP's GUI leaves before it reconstructs
    found = unposed_photos(tmp_path / "project")
    assert found.folder == tmp_path / "project" / "images" and [f[0] for f in found.fingerprint] == \
        ["0.png", "1.png", "2.png"]
    _photos(tmp_path / "plain")
    assert unposed_photos(tmp_path / "plain").folder == tmp_path / "plain"
    assert unposed_photos(make_scene(tmp_path / "scene", {"train": 6})) is None
    (tmp_path / "empty").mkdir()
    assert unposed_photos(tmp_path / "empty") is None


@pytest.mark.slow
def test_render_of_a_project_folder_estimates_poses_instead_of_refusing(tmp_path):
    """Three noise photos cannot be posed: the run tries (and fails cleanly), where it used to refuse."""
    _photos(tmp_path / "project" / "images")
    ckpt = make_checkpoint(tmp_path / "tiny.pt")
    result = run("render", tmp_path / "project", "--out", tmp_path / "views", "--checkpoint", ckpt, "--device",
                 "cpu", "--resolution", 16, "--frames", 1)
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert "estimating them with COLMAP" in result.output and "run `insertnerf poses" not in result.output
    assert not (tmp_path / "views").exists() and sorted(p.name for p in (tmp_path / "project").iterdir()) == ["images"]
