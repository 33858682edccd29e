"""eve3d.evaluate.dtu: the DTU protocol (mask culling, scores on the ground truth)."""
import numpy as np
import scipy

from eve3d.core.fileio import read_mesh
from eve3d.core.io import load_scene
from eve3d.core.raycast import MeshRaycaster, seen_counts
from eve3d.core.scene import Camera, Scene
from eve3d.core.settings import EvalSettings
from eve3d.evaluate import PROTOCOLS, EvalInputs
from eve3d.evaluate.dtu import cull_by_masks
from eve3d.tools.standin import dtu_scale_mat, write_dtu_ground_truth, write_dtu_layout
from tests.helpers import split_long_edges


def test_dtu_culling_removes_exactly_the_vertices_outside_the_dilated_masks(tmp_path):
    """Two cameras, each with a one-pixel mask. A vertex survives when, in every image it
    falls inside, its pixel lies within the 24 px disk around that camera's mask pixel."""
    import open3d as o3d

    from eve3d.core.fileio import write_image

    w, h = 200, 150
    K = np.array([[100.0, 0, w / 2], [0, 100.0, h / 2], [0, 0, 1]])
    cams, marks = [], [(60, 50), (140, 90)]
    for i, (centre, (mx, my)) in enumerate(zip(([0, 0, -5.0], [0.5, 0, -5.0]), marks)):
        mask = np.zeros((h, w, 3), np.uint8)
        mask[my, mx] = 255
        write_image(tmp_path / f"mask{i}.png", mask)
        cams.append(Camera(f"{i}.png", w, h, K, np.eye(3), -np.array(centre), mask_path=tmp_path / f"mask{i}.png"))
    rng = np.random.default_rng(0)
    # Vertices on the z = 0 plane, projecting to pixel centres of camera 0 (camera 1's pixel
    # grid is offset by a whole number of pixels), plus some behind the cameras.
    pix = np.stack([rng.integers(-30, w + 30, 3000), rng.integers(-30, h + 30, 3000)], 1) + 0.5
    v = np.concatenate([np.c_[(pix - K[:2, 2]) / 100.0 * 5.0, np.zeros(len(pix))],
                        rng.uniform(-1, 1, (50, 3)) * [1, 1, 0] + [0, 0, -9]])
    tris = np.arange(len(v) - len(v) % 3).reshape(-1, 3)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(tris))
    expected = np.ones(len(v), dtype=bool)
    for cam, (mx, my) in zip(cams, marks):
        uv, z = cam.project(v)
        px = np.floor(uv)
        inside = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        near = np.hypot(px[:, 0] - mx, px[:, 1] - my) <= 24  # the disk of radius 24 (skimage's disk)
        expected &= ~inside | near
    assert 30 < expected[:3000].sum() < 2500 and expected[3000:].all()
    culled = cull_by_masks(mesh, Scene(root=tmp_path, cameras=cams))
    kept_faces = expected[tris].all(axis=1)
    assert len(culled.triangles) == kept_faces.sum()
    survivors = np.unique(tris[kept_faces])
    assert np.array_equal(np.asarray(culled.vertices), v[survivors])


def test_dtu_protocol_on_the_ground_truth(object_scene, tmp_path):
    """A DTU-layout copy of the object scene (in 'mm', 50 mm per unit): the GT mesh scores
    a Chamfer distance of the order of the sampling density; a shifted mesh scores the shift."""
    import open3d as o3d

    scale = dtu_scale_mat()
    root = tmp_path / "scan1"
    write_dtu_layout(object_scene, root, scale)
    scene = load_scene(root)
    gt = read_mesh(object_scene.gt_mesh)
    files = write_dtu_ground_truth(object_scene, tmp_path, 1, scale)

    def score(mesh_path):
        return PROTOCOLS["dtu"].run(EvalInputs(scene, mesh_path, tmp_path / "m.json", gt=files["stl"],
                                               obs_mask=files["obs_mask"], plane=files["plane"],
                                               settings=EvalSettings(dtu_density=0.5)))

    # The mesh to score: the GT cut into small triangles (mask culling judges vertices),
    # keeping those whose centre some camera sees (no underside).
    tri = split_long_edges(np.asarray(gt.vertices)[np.asarray(gt.triangles)], 0.05)
    tri = tri[seen_counts(MeshRaycaster([gt]), object_scene.cameras, tri.mean(axis=1), stop_at=1) > 0]
    seen = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(tri.reshape(-1, 3)),
                                     o3d.utility.Vector3iVector(np.arange(3 * len(tri)).reshape(-1, 3)))
    o3d.io.write_triangle_mesh(str(tmp_path / "seen.ply"), seen)
    exact = score(tmp_path / "seen.ply")
    assert exact["protocol"] == "dtu" and exact["chamfer"] < 0.5 and exact["n_recon"] > 10_000
    assert len(o3d.io.read_point_cloud(str(tmp_path / "precision.ply")).points) == min(exact["n_recon"], 200_000)
    assert o3d.io.read_point_cloud(str(tmp_path / "recall.ply")).has_colors()
    # every score says which evaluator and which library versions produced it
    assert exact["evaluator"] == "eve3d.evaluate.dtu.evaluate_dtu"
    assert exact["versions"]["open3d"] == o3d.__version__ and exact["versions"]["scipy"] == scipy.__version__
    shifted = seen.translate([0, 0, 0.02])  # 1 mm in DTU units
    o3d.io.write_triangle_mesh(str(tmp_path / "shifted.ply"), shifted)
    moved = score(tmp_path / "shifted.ply")
    # Horizontal surfaces move by the full 1 mm, vertical ones along themselves: the accuracy
    # grows by a large part of the shift and never by more than the shift.
    assert exact["accuracy"] + 0.3 < moved["accuracy"] < exact["accuracy"] + 1.0
