"""eve3d.gaussians.training: the trainer fits a tiny scene, stops on a NaN, starts without sparse points."""
import numpy as np
import pytest
import torch

from eve3d.core.errors import Eve3dError
from eve3d.core.settings import DensifySettings, TrainSettings
from eve3d.gaussians.losses import rgb_loss
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.training import NonFiniteLoss, Trainer
from eve3d.gaussians.view_report import view_metrics
from eve3d.joint import train_joint
from tests.helpers import joint_settings


def test_200_iterations_raise_psnr_by_5_db(tiny_scene, tmp_path):
    s = TrainSettings(iterations=200, sh_degree=0, checkpoint_every=0,
                      densify=DensifySettings(refine_start=50, refine_every=50, reset_every=0))
    trainer = Trainer(tiny_scene, s, tmp_path, "fit")
    trainer.state.set_model(GaussianModel.from_points(tiny_scene.points, tiny_scene.point_colors / 255, 0))
    before = view_metrics(trainer.model, trainer.views, trainer.views.train_ids, s)["psnr"]
    trainer.run(lambda step, view, out: {"rgb": rgb_loss(out.rgb, view.image)})
    after = view_metrics(trainer.model, trainer.views, trainer.views.train_ids, s)["psnr"]
    print(f"PSNR {before:.2f} → {after:.2f} dB")
    assert after - before >= 5.0


def test_nan_stops_with_iteration_and_term_and_keeps_checkpoint(tiny_scene, tmp_path):
    with pytest.raises(Eve3dError, match="joint.dn_weight: expected a number ≥ 0, got nan"):
        joint_settings(dn_weight=float("nan"))  # a NaN setting is refused up front
    s = joint_settings(dn_from=30, checkpoint_every=10)
    s.dn_weight = float("nan")  # so the loss term turns NaN at step 30
    (tmp_path / "point_cloud.ply").write_bytes(b"an earlier run's model")
    with pytest.raises(NonFiniteLoss, match=r"^joint \(pgsr\): loss term depth_normal is not finite at iteration 30;"
                                            r".*checkpoint.pt \(step 30\)$"):
        train_joint(tiny_scene, tmp_path, s)
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == 30
    assert all(torch.isfinite(v).all() for v in ckpt["params"].values())
    # no model of this run is written: the earlier one is intact, and nothing else was
    assert (tmp_path / "point_cloud.ply").read_bytes() == b"an earlier run's model"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt", "point_cloud.ply"]


def test_scene_without_points_starts_from_random_points_in_the_camera_sphere(tiny_scene):
    from dataclasses import replace

    from eve3d.gaussians.training import initial_points

    bare = replace(tiny_scene, points=None, point_colors=None, point_views=None)
    pts, colors = initial_points(bare, 500, np.random.default_rng(0))
    assert pts.shape == (500, 3) and colors.shape == (500, 3)
    dist = np.linalg.norm(pts - bare.center, axis=1)
    assert dist.max() <= bare.radius and np.median(dist) > 0.5 * bare.radius  # uniform in the ball
    same, _ = initial_points(tiny_scene, 500, np.random.default_rng(0))
    assert same is tiny_scene.points


def test_a_job_sharing_the_cores_takes_them_all_once_alone(tiny_scene, tmp_path, monkeypatch):
    """With EVE3D_CORE_SHARE (the workflow's `training_jobs` above 1), a trainer started on one
    thread takes the share's cores while no other job is registered, and unregisters at the end."""
    from eve3d.core.cores import ENV

    share = tmp_path / "cores"
    monkeypatch.setenv(ENV, f"{share}:2")
    s = TrainSettings(iterations=30, sh_degree=0, checkpoint_every=0, densify=DensifySettings(refine_start=1000))
    trainer = Trainer(tiny_scene, s, tmp_path, "fit")
    trainer.state.set_model(GaussianModel.from_points(tiny_scene.points, tiny_scene.point_colors / 255, 0))
    before, seen = torch.get_num_threads(), []
    try:
        torch.set_num_threads(1)
        trainer.run(lambda step, view, out: (seen.append((torch.get_num_threads(), len(list(share.iterdir())))),
                                             {"rgb": rgb_loss(out.rgb, view.image)})[1])
    finally:
        torch.set_num_threads(before)
    assert seen[0] == (2, 1)  # registered, and alone: both cores from the first step
    assert not list(share.iterdir())
