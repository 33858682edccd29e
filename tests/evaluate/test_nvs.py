"""eve3d.evaluate.nvs: a trained model scored on the held-out views (every 8th), as it was trained to render."""
import json

import numpy as np
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import read_image
from eve3d.evaluate import EvalInputs
from eve3d.evaluate.nvs import evaluate_views
from eve3d.gaussians.model import GaussianModel


def test_held_out_views_are_scored_with_the_training_settings(tiny_scene, tmp_path):
    """The sparse points as Gaussians, "trained" at half size on a grey background: of the 8
    views only view 0 is scored, at half size; its render | photo is written beside the
    metrics, and the PSNR is that of the two halves (to the PNG's 8-bit rounding). A model
    trained without the holdout, or without its record, is refused."""
    method = tmp_path / "pgsr"
    method.mkdir()
    GaussianModel.from_points(tiny_scene.points, tiny_scene.point_colors / 255, 0).save_ply(method / "point_cloud.ply")
    trained = {"holdout": 8, "resolution": 0.5, "background": [0.5, 0.5, 0.5], "backend": "cpu", "seed": 3}
    (method / "train_metrics.json").write_text(json.dumps({"settings": trained}))
    inputs = EvalInputs(tiny_scene, method / "point_cloud.ply", method / "metrics.json")
    m = evaluate_views(inputs)
    assert (m["views"], m["holdout"], m["resolution"]) == (1, 8, 0.5) and 0 < m["ssim"] < 1
    pair = read_image(method / "held_out" / f"{tiny_scene.cameras[0].view_id}.png").astype(float) / 255
    assert pair.shape == (24, 64, 3) and sorted(p.name for p in (method / "held_out").iterdir()) == ["000.png"]
    mse = ((pair[:, :32] - pair[:, 32:]) ** 2).mean()
    assert m["psnr"] == pytest.approx(10 * np.log10(1 / mse), abs=0.05)
    (method / "train_metrics.json").write_text(json.dumps({"settings": {**trained, "holdout": 0}}))
    with pytest.raises(Eve3dError, match="trained with holdout 0, so the views the nvs protocol scores"):
        evaluate_views(inputs)
    (method / "train_metrics.json").unlink()
    with pytest.raises(Eve3dError, match="train_metrics.json: the nvs protocol reads the training settings from here"):
        evaluate_views(inputs)
