"""eve3d.tools.standin: a generated scene written as each benchmark's download lays it out, its ground truth aligned."""
import json

import numpy as np
import pytest
from scipy.io import loadmat

from eve3d.core.datasets import BENCHMARKS, dtu_files
from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import read_image, read_mesh
from eve3d.core.io import load_scene
from eve3d.core.io.loader import dataset_format
from eve3d.core.raycast import MeshRaycaster, seen_counts
from eve3d.core.scene import similarity_fit
from eve3d.evaluate import PROTOCOLS, EvalInputs
from eve3d.evaluate.tnt import read_crop
from eve3d.tools.standin import (TNT_OFFICIAL, dtu_scale_mat, run_bench_standin, similarity, standin,
                                 write_dtu_release, write_mipnerf360_release, write_standin, write_tnt_release)


def read_points(path):
    import open3d as o3d

    return np.asarray(o3d.io.read_point_cloud(str(path)).points)


def distance_to_mesh(mesh, points):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


@pytest.mark.parametrize("benchmark, writer, name, fmt", [("dtu", write_dtu_release, "scan24", "dtu"),
                                                         ("tnt", write_tnt_release, "Barn", "tnt"),
                                                         ("mipnerf360", write_mipnerf360_release, "room", "colmap")])
def test_each_benchmarks_stand_in_is_a_layout_it_accepts(benchmark, writer, name, fmt, tiny_scene, tmp_path):
    """``standin`` names the writer and the released scene of ``BENCHMARKS[...].standin``;
    ``write_standin``'s folder passes the benchmark's file checks, is recognised as its
    format and reads back as the same cameras."""
    assert standin(benchmark) == (writer, name)
    folder = write_standin(benchmark, tiny_scene, tmp_path)
    assert folder == tmp_path / name
    assert BENCHMARKS[benchmark].scene(tmp_path, name)["path"] == str(folder)
    assert dataset_format(folder) == fmt
    scene = load_scene(folder)
    assert scene.extras["format"] == fmt and len(scene.cameras) == len(tiny_scene.cameras) == 8
    for cam, truth in zip(scene.cameras, tiny_scene.cameras):
        assert np.allclose(cam.center, truth.center, atol=1e-6) and np.allclose(cam.R, truth.R, atol=1e-6)


def test_dtu_release_crops_the_photos_and_writes_stl_obsmask_and_plane_in_mm(tiny_scene, tmp_path):
    """scan9 cropped by 2 px: the photos are the scene's own pixels cropped, the masks full
    size; the STL points (in mm) lie on the GT surface where a camera sees it, each in a voxel
    the ObsMask marks and no voxel marked without one; the plane has the table below it and
    the object above; the DTU protocol's own check finds the STL on the masks."""
    folder = write_dtu_release(tiny_scene, tmp_path, "scan9", crop=2, stl_points=3000)
    assert folder == tmp_path / "scan9"
    files = dtu_files(tmp_path, "scan9")
    assert BENCHMARKS["dtu"].scene(tmp_path, "scan9") == {"path": str(folder), "dtu": {k: str(v) for k, v in
                                                                                         files.items()}}
    scene = load_scene(folder)
    masks = scene.extras["mask_cameras"]
    for i, (cam, mask_cam, truth) in enumerate(zip(scene.cameras, masks, tiny_scene.cameras)):
        assert (cam.name, cam.width, cam.height) == (f"{i:06d}.png", 60, 44)
        assert (mask_cam.width, mask_cam.height, mask_cam.mask_path.name) == (64, 48, f"{i:03d}.png")
        assert np.array_equal(read_image(cam.image_path), read_image(truth.image_path)[2:-2, 2:-2])
        assert np.array_equal(read_image(mask_cam.mask_path), read_image(tiny_scene.root / "masks" / truth.name))
    cameras = np.load(folder / "cameras.npz")
    assert all(np.array_equal(cameras[f"scale_mat_{i}"], dtu_scale_mat()) for i in range(8))
    assert np.array_equal(scene.to_world, dtu_scale_mat())


    scale = dtu_scale_mat()
    stl_mm = read_points(files["stl"])
    stl = (stl_mm - scale[:3, 3]) / np.diag(scale)[:3]   # back in the scene's frame
    gt = read_mesh(tiny_scene.gt_mesh)
    assert len(stl) == 3000 and distance_to_mesh(gt, stl).max() < 1e-5
    assert seen_counts(MeshRaycaster([gt]), tiny_scene.cameras, stl, stop_at=1).min() == 1
    obs = loadmat(files["obs_mask"])
    mask, bb, res = obs["ObsMask"], obs["BB"], float(np.squeeze(obs["Res"]))
    assert res == 4.0 and np.allclose(bb[1] - bb[0], np.array(mask.shape) * res)
    voxels = np.round((stl_mm - bb[0]) / res).astype(int)
    assert mask[tuple(voxels.T)].all() and mask.sum() == len(np.unique(voxels, axis=0)) < len(stl)
    plane = np.squeeze(loadmat(files["plane"])["P"])
    side = np.c_[stl_mm, np.ones(len(stl_mm))] @ plane
    on_table = np.abs(stl[:, 2]) < 1e-6
    assert on_table.sum() > 300 and (side[on_table] < 0).all() and (side[stl[:, 2] > 0.01] > 0).all()
    check = PROTOCOLS["dtu"].check_ground_truth(EvalInputs(scene, None, tmp_path / "check.json", gt=files["stl"],
                                                           obs_mask=files["obs_mask"], plane=files["plane"]))
    assert check["stl_points_in_masks"] > 0.95


def test_tnt_release_trajectory_transform_and_crop_line_up_with_the_gt(tiny_scene, tmp_path):
    """Meetingroom: the log's cameras, carried by ``_trans.txt`` out of the 'official COLMAP
    frame', are the scene's (the GT frame); the GT points lie on the GT mesh, inside the crop
    box with 5 % to spare; the T&T protocol's own check aligns the cameras and finds the
    sparse points on the GT."""
    folder = write_tnt_release(tiny_scene, tmp_path, "Meetingroom", gt_points=5000)
    assert BENCHMARKS["tnt"].scene(tmp_path, "Meetingroom") == {"path": str(folder)}
    scene = load_scene(folder)
    assert scene.extras["name"] == "Meetingroom" and np.allclose(scene.extras["alignment"], TNT_OFFICIAL, atol=1e-15)
    assert (folder / "Meetingroom_COLMAP_SfM.log").read_text().splitlines()[::5] == [
        f"{i} {i} 0" for i in range(8)]
    trajectory = scene.extras["gt_trajectory"]
    scale = np.cbrt(np.linalg.det(TNT_OFFICIAL[:3, :3]))
    assert scale == pytest.approx(2.0) and len(trajectory) == 8
    for pose, cam in zip(trajectory, tiny_scene.cameras):
        assert np.allclose(pose[3], [0, 0, 0, 1]) and np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-9)
        in_gt = TNT_OFFICIAL @ pose
        assert np.allclose(in_gt[:3, 3], cam.center, atol=1e-9)           # the camera's centre
        assert np.allclose(in_gt[:3, :3] / scale, cam.R.T, atol=1e-9)     # its camera-to-world rotation
        assert not np.allclose(pose[:3, 3], cam.center, atol=0.1)          # which the log holds in another frame


    gt = read_points(folder / "Meetingroom.ply")
    assert len(gt) == 5000 and distance_to_mesh(read_mesh(tiny_scene.gt_mesh), gt).max() < 1e-4
    crop = json.loads((folder / "Meetingroom.json").read_text())
    lo, hi = gt.min(0), gt.max(0)
    polygon = np.array(crop["bounding_polygon"])
    assert np.allclose(polygon[:, :2].min(0), lo[:2] - 0.05 * (hi - lo)[:2])
    assert np.allclose(polygon[:, :2].max(0), hi[:2] + 0.05 * (hi - lo)[:2]) and (polygon[:, 2] == 0).all()
    assert crop["orthogonal_axis"] == "Z" and crop["axis_min"] == pytest.approx(lo[2] - 0.05 * (hi - lo)[2])
    import open3d as o3d

    volume = read_crop(folder / "Meetingroom.json")
    outside = hi + 0.1 * (hi - lo)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.vstack([gt, outside])))
    assert len(volume.crop_point_cloud(cloud).points) == 5000
    check = PROTOCOLS["tnt"].check_ground_truth(EvalInputs(scene, None, tmp_path / "check.json"))
    assert check["trajectory_residual"] < 1e-9 and check["sparse_in_crop"] == len(tiny_scene.points)
    assert check["sparse_near_gt"] > 0.99


def test_mipnerf360_release_writes_jpeg_photos_and_their_area_downscaled_pyramid(tiny_scene, tmp_path):
    """garden: ``images`` and ``images_{2,4,8}`` hold the same JPEG names (upper-case suffix),
    each 1/f of the size and the area mean of the full-size photo (up to JPEG's error); the COLMAP model names
    them with the scene's cameras; ``poses_bounds.npy`` has a row per photo."""
    folder = write_mipnerf360_release(tiny_scene, tmp_path, "garden")
    assert BENCHMARKS["mipnerf360"].scene(tmp_path, "garden") == {"path": str(folder)}
    scene = load_scene(folder)
    names = [f"DSC{i:05d}.JPG" for i in range(8)]
    assert [cam.name for cam in scene.cameras] == names
    for cam, truth in zip(scene.cameras, tiny_scene.cameras):
        assert (cam.width, cam.height) == (64, 48) and np.allclose(cam.K, truth.K)
    for name, truth in zip(names, tiny_scene.cameras):
        photo = read_image(truth.image_path).astype(np.float64)
        for factor, size in ((1, (48, 64)), (2, (24, 32)), (4, (12, 16)), (8, (6, 8))):
            path = folder / ("images" if factor == 1 else f"images_{factor}") / name
            assert path.read_bytes()[:3] == b"\xff\xd8\xff"   # JPEG
            image = read_image(path).astype(np.float64)
            area = photo.reshape(size[0], factor, size[1], factor, 3).mean(axis=(1, 3))
            error, nearest = np.abs(image - area).mean(), np.abs(image - photo[::factor, ::factor]).mean()
            assert image.shape[:2] == size and error < 8, (name, factor, error)   # JPEG's own error: 3.5-6
            assert factor == 1 or error < 0.5 * nearest, (name, factor, error, nearest)   # not every f-th pixel
    assert np.load(folder / "poses_bounds.npy").shape == (8, 17)


def test_similarity_has_its_scale_axis_angle_and_translation():
    m = similarity(2.5, [0, 0, 3.0], np.pi / 2, [1.0, -2.0, 0.5])   # the axis need not be a unit vector
    assert np.allclose(m @ [1, 0, 0, 1], [1.0, 0.5, 0.5, 1]) and np.allclose(m[3], [0, 0, 0, 1])
    axis = np.array([0.3, -1.0, 0.5])
    m = similarity(1.7, axis, 0.7, [0.2, 0.1, -0.3])
    rotation = m[:3, :3] / 1.7
    assert np.allclose(rotation @ rotation.T, np.eye(3)) and np.linalg.det(rotation) == pytest.approx(1)
    assert np.allclose(rotation @ axis, axis)                                # about the axis
    across = np.cross(axis, [1.0, 0, 0])
    assert np.dot(rotation @ across, across) / np.dot(across, across) == pytest.approx(np.cos(0.7))   # by the angle
    assert np.allclose(m[:3, 3], [0.2, 0.1, -0.3])
    points = np.random.default_rng(0).normal(size=(20, 3))
    s, R, t = similarity_fit(points, points @ m[:3, :3].T + m[:3, 3])
    assert s == pytest.approx(1.7) and np.allclose(R, rotation) and np.allclose(t, m[:3, 3])
    assert np.allclose(TNT_OFFICIAL, similarity(2.0, [0.3, -1.0, 0.5], 0.7, [1.0, -2.0, 0.5]))


def test_bench_standin_writes_a_tiny_scene_and_refuses_a_folder_already_there(tmp_path, capsys):
    run_bench_standin("mipnerf360", tmp_path, views=3, width=32, height=24)
    out = capsys.readouterr().out
    assert f"wrote a stand-in room (3 views, 32×24) to {tmp_path / 'room'}" in out
    assert f"--configfile config/benchmarks/mipnerf360.yaml --replace-workflow-config --config root={tmp_path} " \
           f"'only=[room]'" in out
    assert len(load_scene(tmp_path / "room").cameras) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["room"]   # the generated scene went with its temporary folder
    (tmp_path / "scan24").mkdir()
    with pytest.raises(Eve3dError, match=f"{tmp_path / 'scan24'}: already there; give an empty folder"):
        run_bench_standin("dtu", tmp_path)
    assert not any((tmp_path / "scan24").iterdir())
