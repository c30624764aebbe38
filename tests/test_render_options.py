"""RenderOptions: every tuned number of the render path in one frozen dataclass, recorded with every output, and a
render resumed under other options refused in one line."""
from __future__ import annotations

import json
from dataclasses import replace

import pytest
from cli_fixtures import make_checkpoint, make_scene, run

from insertnerf_cli.config import config_from_json, config_to_json
from insertnerf_cli.errors import UserError
from insertnerf_cli.exporters.outputs import STATE_FILE
from insertnerf_cli.exporters.records import RenderConfig
from insertnerf_cli.pipelines.render import render_scene
from insertnerf_cli.rendering.options import RenderOptions
from insertnerf_cli.rendering.prior_blend import BlendOptions

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def scene_and_checkpoint(tmp_path_factory):
    root = tmp_path_factory.mktemp("options")
    return make_scene(root / "scene", {"train": 6, "test": 2}), make_checkpoint(root / "tiny.pt")


def test_options_round_trip_through_json_and_refuse_bad_values():
    options = replace(RenderOptions(), blend=replace(BlendOptions(), margin=2.0))
    assert config_from_json(RenderOptions, json.loads(json.dumps(config_to_json(options)))) == options
    with pytest.raises(ValueError):
        BlendOptions(views=0)
    with pytest.raises(Exception):  # frozen: varied by replace(), never set
        options.blend.margin = 3.0  # type: ignore[misc]


def _config(options: RenderOptions, checkpoint) -> RenderConfig:
    return RenderConfig(frames=3, resolution=16, views=2, checkpoint=checkpoint, options=options)


@pytest.mark.slow
def test_a_render_records_its_options_and_resumes_only_under_the_same_ones(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    out = tmp_path / "views"
    options = RenderOptions()
    render_scene(scene, out, _config(options, ckpt))
    state = json.loads((out / STATE_FILE).read_text())
    assert state["options"] == config_to_json(options)
    assert "blend.margin" in (out / "index.html").read_text()

    (out / "frames" / "00001.png").unlink()  # as if stopped while frame 1 was written
    changed = replace(options, blend=replace(options.blend, margin=2.0))
    with pytest.raises(UserError) as refused:
        render_scene(scene, out, _config(changed, ckpt))
    message = str(refused.value)
    assert "\n" not in message and "options.blend.margin 1.5 -> 2.0" in message and "--overwrite" in message
    assert json.loads((out / STATE_FILE).read_text()) == state  # nothing of the refused run was written
    assert not (out / "frames" / "00001.png").exists()

    summary = render_scene(scene, out, _config(options, ckpt))
    assert (summary.rendered, summary.resumed) == (1, 2)


@pytest.mark.slow
def test_eval_records_its_options_in_the_json_and_the_page(scene_and_checkpoint, tmp_path):
    scene, ckpt = scene_and_checkpoint
    result = run("eval", scene, "--checkpoint", ckpt, "--device", "cpu", "--resolution", 16, "--views", "2,3",
                 "--json", tmp_path / "scores.json", "--out", tmp_path / "report")
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "scores.json").read_text())
    assert report["options"] == config_to_json(RenderOptions())
    assert report["exact"] is False and report["sfm_depth"] is True
    assert "blend.margin" in (tmp_path / "report" / "report.html").read_text()
