"""eve3d.core.photos: photos as users bring them (EXIF-rotated, not photos at all), the image pyramid."""
import shutil

import numpy as np
import pytest
from PIL import Image

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import read_image
from eve3d.core.photos import read_upright, read_view, scan_photos
from eve3d.core.settings import RenderSettings
from tests.helpers import save_sideways


def test_one_orientation_rule(tmp_path):
    """Stages read the pixels as stored (as COLMAP does); the import applies the tag."""
    import cv2

    rng = np.random.default_rng(0)
    upright = cv2.resize(rng.integers(0, 255, (12, 16, 3), dtype=np.uint8), (64, 48), interpolation=cv2.INTER_CUBIC)
    save_sideways(upright, tmp_path / "a.png")  # lossless, so pixels compare exactly
    assert read_image(tmp_path / "a.png").shape == (64, 48, 3)
    assert np.array_equal(read_upright(tmp_path / "a.png"), upright)
    save_sideways(upright, tmp_path / "b.jpg")  # as a phone writes it
    assert read_image(tmp_path / "b.jpg").shape == (64, 48, 3)

    def grey(im):  # JPEG keeps the luma, not the chroma
        return im.astype(float).mean(-1)

    assert np.abs(grey(read_upright(tmp_path / "b.jpg")) - grey(upright)).mean() < 5  # measured 3.2
    assert np.abs(grey(read_upright(tmp_path / "b.jpg")) - grey(upright[::-1, ::-1])).mean() > 20


def test_read_view_reads_the_smallest_pyramid_level_that_is_large_enough(tmp_path):
    from eve3d.core.photos import write_pyramid
    from eve3d.core.scene import Camera

    rng = np.random.default_rng(1)
    images = tmp_path / "images"
    images.mkdir()
    Image.fromarray(rng.integers(0, 255, (300, 400, 3), dtype=np.uint8)).save(images / "v.png")
    write_pyramid(images)
    assert Image.open(tmp_path / "images_2/v.png").size == (200, 150)
    assert Image.open(tmp_path / "images_4/v.png").size == (100, 75)
    assert not (tmp_path / "images_8").exists()  # 37 px would be below the 64 px floor
    cam = Camera("v.png", 400, 300, np.array([[300, 0, 200], [0, 300, 150], [0, 0, 1]]), np.eye(3), np.zeros(3),
                 images / "v.png")
    import cv2

    # 110 px wide: from images_2 (images_4 is too small); 90 px: from images_4
    for side, level in ((110, "images_2"), (90, "images_4")):
        small = RenderSettings(max_side=side).sized(cam)
        assert small.width == side and small.height == round(side * 0.75)
        expect = cv2.resize(read_image(tmp_path / level / "v.png"), (small.width, small.height),
                            interpolation=cv2.INTER_AREA)
        assert np.array_equal(read_view(small), expect)
    rotated = Camera("v.png", 300, 400, cam.K, np.eye(3), np.zeros(3), images / "v.png")
    with pytest.raises(Eve3dError, match="image is 400×300, its camera says 300×400"):
        read_view(rotated)


def test_a_folder_with_a_note_an_empty_jpeg_and_a_duplicate_name(tmp_path, capsys):
    rng = np.random.default_rng(2)
    folder = tmp_path / "images"
    folder.mkdir()
    for name in ("a.jpg", "b.JPG"):
        Image.fromarray(rng.integers(0, 255, (30, 40, 3), dtype=np.uint8)).save(folder / name)
    (folder / "notes.txt").write_text("shot at noon")
    (folder / "empty.jpg").write_bytes(b"")
    (folder / ".DS_Store").write_bytes(b"\0")
    assert [p.name for p in scan_photos(folder)] == ["a.jpg", "b.JPG"]
    err = capsys.readouterr().err
    assert f"{folder / 'notes.txt'}: not an image" in err and f"{folder / 'empty.jpg'}: unreadable image (empty file)" in err
    assert ".DS_Store" not in err
    shutil.copy(folder / "a.jpg", folder / "a.png")
    with pytest.raises(Eve3dError, match="a.png: same name as a.jpg"):
        scan_photos(folder)
    for p in folder.iterdir():
        p.unlink()
    (folder / "empty.jpg").write_bytes(b"")
    with pytest.raises(Eve3dError, match="no readable images"):
        scan_photos(folder)
