import fcntl
import os
from collections.abc import Callable
from pathlib import Path

import pytest

if "PYTEST_XDIST_WORKER" in os.environ:
    # make test's workers (three on two cores): one thread each, set before torch starts. Two
    # workers of two threads each spun against each other (a gradcheck took 51 s, alone 2 s).
    os.environ.setdefault("OMP_NUM_THREADS", "1")

from eve3d.core.io import load_scene
from eve3d.synth import generate
from tests.helpers import TINY_START, run_cli


def pytest_collection_modifyitems(items):
    """The tests marked slow first (each keeps its place among them): under ``make test``'s
    workers the long ones then start early on each, and the many short ones fill in around
    them instead of leaving a worker idle at the end."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


def made_once(tmp_path_factory, name: str, make: Callable[[Path], Path]) -> Path:
    """``make(folder)``, once per test run: the workers of ``make test`` (pytest-xdist) each
    hold their own session fixtures, so the first to ask makes the folder under their shared
    base and the others wait for it rather than making their own (the object scene took 17–23 s
    on each). ``make`` writes the folder atomically (``generate`` does), so it exists only whole."""
    base = tmp_path_factory.getbasetemp()
    if "PYTEST_XDIST_WORKER" in os.environ:
        base = base.parent  # the workers' own folders lie side by side in it
    folder = base / name
    folder.parent.mkdir(parents=True, exist_ok=True)
    with open(base / f"{name.replace('/', '-')}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not folder.exists():
            make(folder)
    return folder


@pytest.fixture(scope="session")
def object_dataset(tmp_path_factory) -> Path:
    """The embedded default object scene at the CPU preset's size (320×240, 32 views)."""
    return made_once(tmp_path_factory, "data/object", lambda out: generate("object", out))


@pytest.fixture(scope="session")
def room_dataset(tmp_path_factory) -> Path:
    """The embedded default room scene at the CPU preset's size (320×240, 32 views)."""
    return made_once(tmp_path_factory, "data/room", lambda out: generate("room", out))


@pytest.fixture(scope="session")
def object_scene(object_dataset):
    return load_scene(object_dataset)


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """An 8-view 64×48 object scene: small enough for training tests; it starts from exact
    surface samples (``TINY_START``: SIFT finds nothing to match at this size)."""
    return made_once(tmp_path_factory, "tiny/object", lambda out: generate("object", out, views=8, width=64, height=48,
                                                                     surface_samples=TINY_START))


@pytest.fixture(scope="session")
def tiny_scene(tiny_dataset):
    return load_scene(tiny_dataset)


@pytest.fixture(scope="session")
def tiny_sky_scene(tmp_path_factory):
    """``tiny_scene``'s object before a plain sky, as photos have one."""
    return load_scene(made_once(tmp_path_factory, "tiny/object-sky", lambda out: generate(
        "object", out, views=8, width=64, height=48, surface_samples=TINY_START, background="sky")))


@pytest.fixture(scope="session")
def object_photos(tmp_path_factory) -> Path:
    """16 photos of the object from a 120° arc at 480×360, images only (the poses hidden
    under gt/): a user's folder of photos, which SfM has to pose. Read only: a test that
    changes the photos copies them first."""
    return made_once(tmp_path_factory, "photos/object", lambda out: generate(
        "object", out, views=16, width=480, height=360, arc=120, images_only=True,
        surface_samples=TINY_START))  # the points go under gt/, unused


@pytest.fixture(scope="session")
def object_photos_sfm(object_photos, tmp_path_factory) -> Path:
    """``eve3d sfm`` of ``object_photos`` on one thread (bit-reproducible): the posed dataset."""
    out = tmp_path_factory.mktemp("photos-sfm") / "sfm"
    r = run_cli("sfm", object_photos, out, "--threads", "1")
    assert r.returncode == 0, r.stderr[-2000:]
    return out


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
