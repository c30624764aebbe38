"""Fixtures shared by the test modules."""
from pathlib import Path

import pytest
import torch


@pytest.fixture
def one_thread():
    """Tiny models on a shared 2-core machine run far faster on one thread than fighting for two."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """A tiny random-init checkpoint (cli_fixtures.make_checkpoint), made once per test module that asks for it."""
    from cli_fixtures import make_checkpoint

    return make_checkpoint(tmp_path_factory.mktemp("checkpoint") / "tiny.pt")


@pytest.fixture
def known():
    """scene_fixtures.known_scene(): 5 cameras on a ring with their images and points, a fresh one per test."""
    from scene_fixtures import known_scene

    return known_scene()
