"""eve3d.core.datasets: a benchmark's scenes found in its download's layout, misplaced files named."""
import pytest

from eve3d.core.datasets import BENCHMARKS, dtu_files, dtu_scan, expand_benchmark
from eve3d.core.errors import Eve3dError


def test_dtu_scenes_and_their_evaluation_files_by_name(tmp_path):
    assert dtu_scan("scan24") == 24
    with pytest.raises(Eve3dError, match="scan24a: a DTU scene is named scanN"):
        dtu_scan("scan24a")
    files = dtu_files(tmp_path, "scan9")  # only the STL number is zero-padded
    assert files == {"stl": tmp_path / "Points/stl/stl009_total.ply", "obs_mask": tmp_path / "ObsMask/ObsMask9_10.mat",
                     "plane": tmp_path / "ObsMask/Plane9.mat"}


def test_a_misplaced_file_is_named_with_where_it_was_found(tmp_path):
    scan = tmp_path / "scan9"
    for folder in ("image", "mask", "Points/stl", "ObsMask"):
        (scan.parent / folder if folder[0].isupper() else scan / folder).mkdir(parents=True)
    (scan / "cameras.npz").write_bytes(b"")
    for path in dtu_files(tmp_path, "scan9").values():
        path.write_bytes(b"")
    config = {"benchmark": "dtu", "root": str(tmp_path), "scenes": {"scan9": {"evaluate": {"tau": 1}}}}
    scene = expand_benchmark(config)["scenes"]["scan9"]
    assert scene["path"] == str(scan) and scene["evaluate"] == {"tau": 1}  # the scene's own keys kept
    assert scene["dtu"]["plane"] == str(tmp_path / "ObsMask/Plane9.mat")
    (tmp_path / "ObsMask/Plane9.mat").rename(tmp_path / "Plane9.mat")
    with pytest.raises(Eve3dError, match=r"c.yaml: scenes.scan9 \(dtu benchmark\): .*ObsMask/Plane9.mat: not found "
                                         r"\(DTU's official ObsMask folder file of scan9\); found .*/Plane9.mat: move it"):
        expand_benchmark({**config, "scenes": {"scan9": None}}, "c.yaml")
    with pytest.raises(Eve3dError, match="benchmark: unknown benchmark 'dtu2'; choose one of dtu, tnt, mipnerf360"):
        expand_benchmark({"benchmark": "dtu2"})
    assert BENCHMARKS["tnt"].published_rows()[0] == {"source": "published (Eve3D paper)", "method": "eve3d",
                                                     "fscore": 0.58}
