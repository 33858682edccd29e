from pathlib import Path

import pytest

from eve3d.core.io import load_scene
from eve3d.synth import generate
from tests.helpers import TINY_START


@pytest.fixture(scope="session")
def object_dataset(tmp_path_factory) -> Path:
    """The embedded default object scene at the CPU preset's size (320×240, 32 views)."""
    return generate("object", tmp_path_factory.mktemp("data") / "object")


@pytest.fixture(scope="session")
def object_scene(object_dataset):
    return load_scene(object_dataset)


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """An 8-view 64×48 object scene: small enough for training tests; it starts from exact
    surface samples (``TINY_START``: SIFT finds nothing to match at this size)."""
    return generate("object", tmp_path_factory.mktemp("tiny") / "object", views=8, width=64, height=48,
                    surface_samples=TINY_START)


@pytest.fixture(scope="session")
def tiny_scene(tiny_dataset):
    return load_scene(tiny_dataset)


@pytest.fixture
def one_thread(monkeypatch):
    """Single-threaded rasterisation on the CPU: gradient sums in a fixed order,
    bit-reproducible (gsplat's CUDA backward adds in no fixed order)."""
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
