"""eve3d.core.io.dtu: DTU's projection matrices decomposed, its layout read as normalised cameras."""
import numpy as np
from scipy.spatial.transform import Rotation

from eve3d.core.io import load_scene
from eve3d.core.io.dtu import decompose_projection
from eve3d.tools.standin import dtu_scale_mat, write_dtu_layout


def test_dtu_world_mat_decomposes_and_recomposes():
    rng = np.random.default_rng(1)
    for _ in range(20):
        K = np.array([[rng.uniform(500, 3000), rng.uniform(-1, 1), rng.uniform(500, 900)],
                      [0, rng.uniform(500, 3000), rng.uniform(400, 700)], [0, 0, 1]])
        R = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
        t = rng.normal(0, 300, 3)
        P = rng.uniform(0.1, 10) * rng.choice([-1, 1]) * (K @ np.hstack([R, t[:, None]]))
        K2, R2, t2 = decompose_projection(P)
        assert np.allclose(K2, K, rtol=1e-6, atol=1e-6)
        assert np.allclose(R2, R, atol=1e-6) and np.linalg.det(R2) > 0
        P2 = K2 @ np.hstack([R2, t2[:, None]])
        Pn = P / (np.linalg.norm(P[2, :3]) * np.sign(np.linalg.det(P[:, :3])))  # P's own scale removed
        assert np.abs(P2 - Pn).max() / np.abs(Pn).max() < 1e-6


def test_dtu_reader_recovers_normalised_cameras(object_scene, tmp_path):
    write_dtu_layout(object_scene, tmp_path / "scan1", dtu_scale_mat())
    dtu = load_scene(tmp_path / "scan1")
    assert dtu.kind == "object" and np.array_equal(dtu.to_world, dtu_scale_mat())
    for a, b in zip(object_scene.cameras, dtu.cameras):
        assert np.allclose(a.K, b.K, rtol=1e-9) and np.allclose(a.R, b.R, atol=1e-9)
        assert np.allclose(a.center, b.center, atol=1e-9)
        assert b.mask_path is not None
