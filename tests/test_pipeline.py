"""Oracle depth → TSDF → evaluation on the embedded default scene."""
import json
from pathlib import Path

import numpy as np
import pytest

from eve3d.maps import load_maps
from eve3d.raycast import MeshRaycaster
from eve3d.synth import generate
from tests.conftest import run_cli


def test_synthetic_scene_is_consistent(object_scene):
    """Sparse points lie on the GT surface and project where the GT depth says."""
    caster = MeshRaycaster.from_file(object_scene.gt_mesh)
    cam = object_scene.cameras[3]
    seen = [i for i, v in enumerate(object_scene.point_views) if 3 in v]
    uv, z = cam.project(object_scene.points[seen])
    assert np.allclose(caster.cast_uv(cam, uv).depth, z, rtol=1e-4)
    assert object_scene.kind == "object" and len(object_scene.cameras) == 32


@pytest.fixture(scope="module")
def room_dataset(tmp_path_factory) -> Path:
    """The built-in room scene at its default size."""
    return generate("room", tmp_path_factory.mktemp("data") / "room")


@pytest.mark.parametrize("which", ["object", "room"])
def test_oracle_tsdf_mesh_scores_high(which, object_dataset, room_dataset, tmp_path):
    """The exact depth of the built-in scenes, fused at the cpu preset's coarse voxel,
    scores F ≥ 0.98 under the synthetic protocol."""
    dataset = object_dataset if which == "object" else room_dataset
    priors, mesh, metrics = tmp_path / "priors", tmp_path / "mesh.ply", tmp_path / "metrics.json"
    r = run_cli("stereo-depth", "--backend", "oracle", "--scene", dataset, "--out", priors)
    assert r.returncode == 0, r.stderr
    maps = load_maps(priors / "000.npz")
    assert maps["depth"].dtype == np.float32 and (priors / "000.depth.png").exists()
    r = run_cli("mesh", "--scene", dataset, "--depth", priors, "--out", mesh, "--coarsen", "5")
    assert r.returncode == 0, r.stderr
    r = run_cli("evaluate", "--mesh", mesh, "--gt", dataset / "gt/mesh.ply", "--scene", dataset, "--out", metrics)
    assert r.returncode == 0, r.stderr
    assert "tau = " in r.stdout
    m = json.loads(metrics.read_text())
    assert m["fscore"] >= 0.98, m
    assert m["chamfer"] < m["tau"] / 5
