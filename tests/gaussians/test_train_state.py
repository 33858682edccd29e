"""eve3d.gaussians.train_state: the checkpoint resumes only the run it was written by."""
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.training import Trainer
from tests.helpers import joint_settings


def test_changed_settings_do_not_resume_a_stale_checkpoint(tiny_scene, tmp_path, capsys):
    trainer = Trainer(tiny_scene, joint_settings(), tmp_path, "a")
    trainer.state.set_model(GaussianModel.from_points(tiny_scene.points, None, 1))
    trainer.checkpoint.save(trainer.state)
    other = Trainer(tiny_scene, joint_settings(iterations=61), tmp_path, "b")
    other.state.set_model(GaussianModel.from_points(tiny_scene.points, None, 1))
    assert not other.checkpoint.resume(other.state)
    assert "other settings" in capsys.readouterr().err
