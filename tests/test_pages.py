"""The pages render and eval write: they exist, are recorded like every other output, link only to files inside
their own folder (relative, no http), list every frame / held-out view, and escape the user's names."""
from __future__ import annotations

import json
import re
from pathlib import Path
from urllib.parse import unquote

import pytest
from cli_fixtures import make_scene, run

from insertnerf_cli.files.outdir import OutputRecord
from insertnerf_cli.exporters.report.svg import ViewAxes, line_chart

pytestmark = pytest.mark.usefixtures("one_thread")
_REFERENCE = re.compile(r'(?:src|href|poster)="([^"]*)"')


def _references(page: Path) -> list[str]:
    """Every file a page refers to, checked to be a relative path to an existing file inside its folder."""
    text = page.read_text(encoding="utf-8")
    assert "http" not in text.lower() and "<script" not in text.lower() and "@import" not in text
    refs = [unquote(r) for r in _REFERENCE.findall(text)]
    folder = page.parent.resolve()
    for ref in refs:
        target = (page.parent / ref).resolve()
        assert not ref.startswith("/") and folder in target.parents, ref
        assert target.is_file(), ref
    return refs


@pytest.mark.slow
def test_render_page_lists_every_frame_and_links_inside_the_folder(checkpoint, tmp_path):
    scene = make_scene(tmp_path / "my <scene> & co", {"train": 6})
    out = tmp_path / "views"
    common = ("--checkpoint", checkpoint, "--device", "cpu", "--resolution", 16, "--views", 2)
    result = run("render", scene, "--out", out, "--frames", 4, "--pointcloud", *common)
    assert result.exit_code == 0, result.output
    page = out / "index.html"
    refs = _references(page)
    for i in range(4):
        for sub in ("frames", "depth_vis", "depth"):
            assert f"{sub}/{i:05d}.png" in refs
    assert {"video.mp4", "depth.mp4", "cameras.json", "pointcloud.ply"} <= set(refs)
    text = page.read_text()
    assert "my &lt;scene&gt; &amp; co" in text and "<scene>" not in text  # the user's folder name, escaped
    assert text.count("<svg") == 2  # the camera path from above and from the side
    assert "index.html" in OutputRecord(out, "render").paths and "pointcloud.ply" in OutputRecord(out, "render").paths
    # --overwrite with other settings removes the page with the rest, and writes the new one.
    again = run("render", scene, "--out", out, "--frames", 2, "--overwrite", *common)
    assert again.exit_code == 0, again.output
    assert not (out / "pointcloud.ply").exists() and not (out / "frames" / "00003.png").exists()
    assert "frames/00001.png" in _references(page) and "frames/00002.png" not in _references(page)


@pytest.mark.slow
def test_eval_report_has_thumbnails_means_and_a_views_chart(checkpoint, tmp_path):
    scene = make_scene(tmp_path / "scene", {"train": 6, "test": 2})
    out = tmp_path / "report"
    result = run("eval", scene, "--checkpoint", checkpoint, "--device", "cpu", "--resolution", 16, "--views", "2,4",
                 "--out", out, "--json", tmp_path / "scores.json")
    assert result.exit_code == 0, result.output
    refs = _references(out / "report.html")
    assert sorted(set(refs)) == sorted(f"views_{n}/{i:05d}.png" for n in (2, 4) for i in (6, 7))
    text = (out / "report.html").read_text()
    assert "PSNR against the number of reference views" in text and "<polyline" in text
    scores = json.loads((tmp_path / "scores.json").read_text())
    for count in scores["by_count"]:
        assert f"{count['psnr']:.2f}" in text
    assert "report.html" in OutputRecord(out, "eval").paths
    one = run("eval", scene, "--checkpoint", checkpoint, "--device", "cpu", "--resolution", 16, "--views", "2",
              "--out", out, "--overwrite")
    assert one.exit_code == 0, one.output
    assert sorted(set(_references(out / "report.html"))) == ["00006.png", "00007.png"]  # the list's files are gone
    assert not (out / "views_2").exists() and "<polyline" not in (out / "report.html").read_text()


def test_line_chart_puts_a_higher_value_higher():
    svg = line_chart([3, 6, 10], [20.0, 21.0, 22.5], "views", "PSNR")
    circles = [float(y) for y in re.findall(r'<circle cx="[^"]*" cy="([^"]*)"', svg)]
    assert len(circles) == 3 and circles[0] > circles[1] > circles[2]  # SVG y grows downwards
    assert "22.50" in svg


def test_view_axes_put_up_last_and_the_spread_first():
    centres = [[x, 0.1 * x, 1.0] for x in range(-3, 4)]
    ups = [[0.0, 0.0, 1.0]] * 7
    import numpy as np

    axes = ViewAxes.of(np.array(centres, float), np.array(ups, float)).matrix
    np.testing.assert_allclose(axes[2], [0, 0, 1], atol=1e-9)
    assert abs(axes[0] @ np.array([1.0, 0.1, 0.0]) / np.hypot(1.0, 0.1)) == pytest.approx(1.0)
    np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-9)
