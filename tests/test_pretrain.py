"""eve3d.pretrain: the pretrain stage (re-initialisation from rendered depth, simplification by blending weight)."""
import json
import re

import numpy as np
import pytest
import torch

from eve3d.core.photos import scene_tone_curve
from eve3d.core.scene import Camera
from eve3d.core.settings import DensifySettings, PretrainSettings, RenderSettings
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.render import render_model
from eve3d.gaussians.render.projection import CameraTensors
from eve3d.gaussians.views import View
from eve3d.pretrain import blend_weights, pretrain


def test_blend_weights_are_each_gaussians_alpha_times_transmittance_over_the_views():
    """Two overlapping Gaussians, the front one first: its weight is its alpha summed over
    the pixels of both views; the one behind gets the rest of the composite's alpha."""
    params = {"means": torch.tensor([[0.0, 0, 2], [0.05, 0.02, 3]]), "quats": torch.tensor([[1.0, 0, 0, 0]] * 2),
              "log_scales": torch.full((2, 3), -2.5), "logit_opacities": torch.logit(torch.tensor([0.6, 0.5])),
              "sh0": torch.zeros(2, 1, 3), "shN": torch.zeros(2, 0, 3)}
    model = GaussianModel(params, 0)
    K = np.array([[30.0, 0, 12], [0, 30, 9], [0, 0, 1]])
    cams = [Camera("a.png", 24, 18, K, np.eye(3), np.zeros(3)), Camera("b.png", 24, 18, K, np.eye(3), np.array([0.1, 0, 0]))]
    views = [View(i, c, CameraTensors.from_camera(c), torch.zeros(18, 24, 3)) for i, c in enumerate(cams)]
    rendering = RenderSettings(backend="cpu")
    weights = blend_weights(model, views, rendering)
    front = GaussianModel({k: v[:1] for k, v in params.items()}, 0)
    alone = sum(float(render_model(front, v.cam, rendering).alpha.sum()) for v in views)
    both = sum(float(render_model(model, v.cam, rendering).alpha.sum()) for v in views)
    assert alone > 10 and both > alone
    assert float(weights[0]) == pytest.approx(alone, rel=1e-5)
    assert float(weights[1]) == pytest.approx(both - alone, rel=1e-4)


def test_a_short_pretrain_reinitialises_simplifies_and_writes_its_outputs(tiny_scene, tmp_path, capsys):
    """30 steps: Gaussians drawn from the rendered depth at step 10 (at most 400: no more than
    the pixels it covers well), half of them (those of most blending weight) kept at step 20,
    no densification: the model written has those; the tone curve is the scene's; the record
    scores the held-out view 0 and the 7 others."""
    s = PretrainSettings(iterations=30, sh_degree=0, checkpoint_every=10, previews=1, reinit_at=(10,),
                         reinit_points=400, simplify_at=(20,), simplify_keep=0.5,
                         densify=DensifySettings(refine_start=100, refine_stop=0, reset_every=0))
    metrics = pretrain(tiny_scene, tmp_path, s)
    err = capsys.readouterr().err
    drawn = int(re.search(r"pretrain: step 10: re-initialised (\d+) Gaussians from rendered depth", err).group(1))
    kept = int(re.search(r"pretrain: step 20: simplified to (\d+) Gaussians", err).group(1))
    assert 100 < drawn <= 400  # measured 247
    assert round(drawn / 2) - 5 <= kept <= round(drawn / 2)  # half, less any that no training view sees
    model = GaussianModel.load_ply(tmp_path / "point_cloud.ply")
    assert len(model) == kept == metrics["gaussians"]
    curve = json.loads((tmp_path / "tone_curve.json").read_text())
    assert curve == scene_tone_curve(tiny_scene, s.equalize).tolist() and len(curve) == 256
    assert all(a <= b for a, b in zip(curve, curve[1:]))
    record = json.loads((tmp_path / "train_metrics.json").read_text())
    assert record["record"] == "training" and record["iterations"] == 30
    assert record["held_out"]["views"] == 1 and record["train"]["views"] == 7 and record["held_out"]["psnr"] > 5
    assert sorted(p.name for p in (tmp_path / "previews").iterdir()) == ["000.depth.png", "000.normal.png", "000.rgb.png"]
    assert not (tmp_path / "checkpoint.pt").exists()


def test_coarse_steps_see_every_view_at_the_coarse_size_then_at_the_training_size(tiny_scene, tmp_path):
    """Coarse to fine: the first half of the steps (``coarse_until``) render and fit each view
    at most ``coarse_side`` px a side (the photo read at that size), the later ones at the
    training size; the model fits the held-out view about as well as one trained at full size
    throughout. Views no larger than ``coarse_side`` have no coarse steps."""
    from eve3d.pretrain import setup_pretrain

    short = DensifySettings(refine_start=10, refine_every=10, refine_stop=40, reset_every=0)
    cam = tiny_scene.cameras[0]
    full, half = (cam.height, cam.width), (cam.height // 2, cam.width // 2)
    scores = {}
    for until, side, seen in ((0, 256, [full] * 60), (0.5, max(half), [half] * 30 + [full] * 30),
                              (0.5, max(full), [full] * 60)):
        s = PretrainSettings(iterations=60, sh_degree=0, checkpoint_every=0, previews=0, reinit_at=(), simplify_at=(),
                             coarse_until=until, coarse_side=side, densify=short)
        run = setup_pretrain(tiny_scene, tmp_path / f"{until}-{side}", s)
        sizes = []

        def loss(step, view, out, run=run, sizes=sizes):
            assert out.rgb.shape == view.image.shape  # the photo at the size rendered
            sizes.append(tuple(view.image.shape[:2]))
            return run.loss(step, view, out)

        run.trainer.run(loss, run.events)
        assert sizes == seen
        metrics = run.trainer.finish(tmp_path / f"{until}-{side}", lambda sc: sc, "depth_expected")
        scores[until, side] = metrics["held_out"]["psnr"]
    print(f"held-out PSNR: full size {scores[0, 256]:.2f} dB, coarse to fine {scores[0.5, max(half)]:.2f} dB")
    assert scores[0.5, max(half)] > scores[0, 256] - 1.0
