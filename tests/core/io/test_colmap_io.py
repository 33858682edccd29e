"""eve3d.core.io.colmap: COLMAP models written and read back exactly, read without open3d."""
import sys

import numpy as np
import pytest

from eve3d.core.io.colmap import read_colmap, write_colmap


@pytest.mark.parametrize("binary", [True, False])
def test_colmap_round_trip_is_exact(object_scene, tmp_path, binary):
    model = tmp_path / "sparse"
    write_colmap(object_scene, model, binary=binary)
    back = read_colmap(model, object_scene.root / "images")
    assert [c.name for c in back.cameras] == [c.name for c in object_scene.cameras]
    for a, b in zip(object_scene.cameras, back.cameras):
        assert np.array_equal(a.K, b.K) and (a.width, a.height) == (b.width, b.height)
        # COLMAP stores R as a quaternion: R comes back to the rounding of that conversion.
        assert np.abs(a.R - b.R).max() < 1e-14 and np.array_equal(a.t, b.t)
    assert np.array_equal(back.points, object_scene.points)
    assert np.array_equal(back.point_colors, object_scene.point_colors)
    assert all(np.array_equal(u, v) for u, v in zip(back.point_views, object_scene.point_views))


def test_a_model_is_read_where_open3d_is_not_installed(object_scene, tmp_path, monkeypatch):
    """The training stages read their scene on a GPU machine with pycolmap and no open3d."""
    write_colmap(object_scene, tmp_path / "sparse")
    monkeypatch.setitem(sys.modules, "open3d", None)  # `import open3d` now raises ImportError
    back = read_colmap(tmp_path / "sparse", object_scene.root / "images")
    assert [c.name for c in back.cameras] == [c.name for c in object_scene.cameras]
    assert np.array_equal(back.points, object_scene.points)


def test_sfm_uses_the_threads_the_job_has(monkeypatch):
    """-1 (the default) is the workflow's share of the cores (OMP_NUM_THREADS), or pycolmap's
    every core without one; a count given is kept; each reaches SIFT, matching and mapping."""
    from eve3d.core.io.colmap import extraction_options, mapping_options, sfm_threads
    from eve3d.core.settings import SfmSettings

    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert sfm_threads(SfmSettings()) == 3 and sfm_threads(SfmSettings(threads=1)) == 1
    assert extraction_options(SfmSettings()).num_threads == mapping_options(SfmSettings()).num_threads == 3
    for unset in ("", "many", "0"):
        monkeypatch.setenv("OMP_NUM_THREADS", unset)
        assert sfm_threads(SfmSettings()) == -1
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert sfm_threads(SfmSettings()) == -1 and sfm_threads(SfmSettings(threads=2)) == 2


def test_sift_estimates_affine_shapes_only_when_asked():
    """``sfm.affine_features`` reaches SIFT's options; off by default (monstree's photos lose
    points and held-out PSNR with it)."""
    from eve3d.core.io.colmap import extraction_options
    from eve3d.core.settings import SfmSettings

    assert not extraction_options(SfmSettings()).sift.estimate_affine_shape
    assert extraction_options(SfmSettings(affine_features=True)).sift.estimate_affine_shape


def test_auto_matches_every_pair_up_to_the_limit_then_in_sequence():
    from eve3d.core.settings import SfmSettings

    auto = SfmSettings()
    assert auto.matcher == "auto" and auto.exhaustive_up_to == 64
    assert auto.matcher_for(64) == "exhaustive" and auto.matcher_for(65) == "sequential"
    assert SfmSettings(matcher="exhaustive").matcher_for(500) == "exhaustive"
    assert SfmSettings(matcher="sequential").matcher_for(3) == "sequential"


def test_sequential_pairs_follow_the_photos_order_not_their_size_folders():
    """COLMAP's pairs (the next 10, and those 2^k ahead) in the order the photos are given: a
    portrait photo between two landscape ones is matched with both, whatever its folder."""
    from eve3d.core.io.colmap import sequential_pairs

    names = [f"{'960x1280' if i % 3 else '1280x960'}/IMG_{i:04d}.png" for i in range(23)]
    pairs = sequential_pairs(names)
    assert len(pairs) == len(set(pairs)) == 182  # of the 253 exhaustive pairs
    assert pairs[:2] == [(names[0], names[1]), (names[0], names[2])]
    index = {n: i for i, n in enumerate(names)}
    gaps = {index[b] - index[a] for a, b in pairs}
    assert gaps == set(range(1, 11)) | {16}  # 1..10, and 2^4 (2^5 = 32 is past the last photo)
    assert len(sequential_pairs([f"{i}.png" for i in range(64)])) == 665 and sequential_pairs(names[:1]) == []
