"""eve3d.core.fileio: artefacts written atomically, images checked and read as stored."""
import numpy as np
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_dir, atomic_path, check_image, list_images, read_image, write_image


def test_an_artefact_appears_whole_or_not_at_all(tmp_path):
    """A failed write leaves the earlier artefact and no temporary file; a finished one
    replaces it. The same for a folder."""
    target = tmp_path / "out" / "a.json"
    with atomic_path(target) as tmp:
        assert tmp.parent == target.parent and tmp != target
        tmp.write_text("first")
    assert target.read_text() == "first"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert target.read_text() == "first" and sorted(p.name for p in target.parent.iterdir()) == ["a.json"]
    folder = tmp_path / "maps"
    with atomic_dir(folder) as tmp:
        (tmp / "x.npz").write_bytes(b"1")
    with pytest.raises(RuntimeError), atomic_dir(folder) as tmp:
        (tmp / "y.npz").write_bytes(b"2")
        raise RuntimeError("killed")
    assert sorted(p.name for p in folder.iterdir()) == ["x.npz"] and sorted(p.name for p in tmp_path.iterdir()) == [
        "maps", "out"]


def test_images_round_trip_and_bad_ones_are_named(tmp_path):
    rgb = np.random.default_rng(0).integers(0, 255, (6, 8, 3), dtype=np.uint8)
    write_image(tmp_path / "a.png", rgb)
    assert np.array_equal(read_image(tmp_path / "a.png"), rgb)  # RGB in, RGB out (OpenCV's BGR inside)
    assert check_image(tmp_path / "a.png", (8, 6)) == (8, 6)
    with pytest.raises(Eve3dError, match="image is 8×6 but its camera says 6×8"):
        check_image(tmp_path / "a.png", (6, 8))
    (tmp_path / "b.png").write_bytes((tmp_path / "a.png").read_bytes()[:40])
    with pytest.raises(Eve3dError, match="b.png: corrupt or unreadable image"):
        check_image(tmp_path / "b.png")
    (tmp_path / "notes.txt").write_text("x")
    assert list_images(tmp_path) == [tmp_path / "a.png", tmp_path / "b.png"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(Eve3dError, match="empty: no images"):
        list_images(tmp_path / "empty")
