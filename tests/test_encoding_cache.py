"""Reference-view encodings are kept per view: a frame encodes only the views its predecessors did not use."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from insertnerf_cli.rendering.options import ColourOptions, RenderOptions
from insertnerf_cli.model import EncodedViews, InsertNeRF, SourceViews
from insertnerf_cli.rendering.view_renderer import ViewRenderer, colour_size
from insertnerf_cli.scenes import load_scene, normalize_scene
from model_fixtures import TINY, sphere_views  # noqa: F401
from scene_fixtures import known_scene, write_blender

pytestmark = pytest.mark.usefixtures("one_thread")


def _close(a: EncodedViews, b: EncodedViews) -> None:
    for x, y in zip(a.features, b.features):
        torch.testing.assert_close(x, y, atol=1e-5, rtol=1e-4)
    for name in ("images", "projection", "centers"):
        torch.testing.assert_close(getattr(a, name), getattr(b, name))
    assert (a.height, a.width) == (b.height, b.width)


def test_joined_per_view_encodings_equal_encoding_the_set():
    torch.manual_seed(0)
    model = InsertNeRF(TINY).eval()
    views = sphere_views(4, 16)
    with torch.no_grad():
        whole = model.encode(views)
        subset = model.encode(SourceViews(views.images[[1, 3, 0]], views.cameras[[1, 3, 0]]))
    _close(EncodedViews.join([whole.select([1, 3]), whole.select([0])]), subset)


def test_renderer_encodes_each_view_once_while_frames_share_views(tmp_path):
    torch.manual_seed(0)
    scene, _ = normalize_scene(load_scene(write_blender(tmp_path / "scene", known_scene(n=6))))
    model = InsertNeRF(TINY).eval()
    encoded_counts = []
    encode = model.encode

    def counting_encode(views):
        encoded_counts.append(len(views))
        return encode(views)

    model.encode = counting_encode
    renderer = ViewRenderer(model, scene, (16, 16), views=3)
    first = renderer._encoded([2, 0, 1])
    second = renderer._encoded([1, 2, 3])
    assert encoded_counts == [3, 1]  # only view 3 is new for the second frame
    assert len(first) == len(second) == 3
    images, cams = scene.load_sizes([1, 2, 3], [(16, 16)])[0], scene.cameras.subset([1, 2, 3]).rescale(16, 16)
    with torch.no_grad():
        _close(second, encode(SourceViews(images, cams)))


def test_colours_come_from_the_photos_at_up_to_twice_the_frame_size(tmp_path):
    assert colour_size((16, 24), (64, 96), 2.0) == (32, 48)
    assert colour_size((16, 24), (20, 30), 2.0) == (20, 30)  # never above the photos' own size
    assert colour_size((16, 24), (16, 24), 2.0) is None and colour_size((16, 24), (64, 96), 1.0) is None
    torch.manual_seed(0)
    scene, _ = normalize_scene(load_scene(write_blender(tmp_path / "scene", known_scene(n=4))))
    model = InsertNeRF(TINY).eval()
    h, w = scene.cameras.height // 2, scene.cameras.width // 2
    encoded = ViewRenderer(model, scene, (h, w), views=2)._encoded([3, 1])
    photos = scene.load_sizes([1, 3], [(2 * h, 2 * w)])[0]
    torch.testing.assert_close(encoded.colours, photos.permute(0, 3, 1, 2))
    assert (encoded.height, encoded.width) == (h, w)
    assert ViewRenderer(model, scene, (h, w), views=2,
                        options=RenderOptions(colours=ColourOptions(scale=1.0)))._encoded([3, 1]).colours is None


def test_both_sizes_come_from_one_decode_of_each_photo(tmp_path, monkeypatch):
    import insertnerf_cli.scenes.base as base

    scene = load_scene(write_blender(tmp_path / "scene", known_scene(n=3)))
    decoded: list = []
    read = base.read_rgb
    monkeypatch.setattr(base, "read_rgb", lambda *a, **k: decoded.append(a[0]) or read(*a, **k))
    small, large = scene.load_sizes([2, 0], [(12, 16), (24, 32)])
    assert len(decoded) == 2  # one read per photo, whatever the number of sizes
    for images, (h, w) in ((small, (12, 16)), (large, (24, 32))):
        torch.testing.assert_close(images, torch.from_numpy(np.stack([scene.load_image(i, h, w) for i in (2, 0)])))
