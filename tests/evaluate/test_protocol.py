"""eve3d.evaluate.protocol: a protocol names what it is missing and the dataset it needs, and
records who scored; the registry is what the protocol modules declare."""
import importlib
import pkgutil

import pytest

import eve3d.evaluate as evaluate
from eve3d.core.errors import Eve3dError
from eve3d.core.io.loader import formats
from eve3d.evaluate.protocol import EvalInputs, Protocol


def _score(inputs: EvalInputs) -> dict:
    return {"fscore": 0.5, "mesh": str(inputs.reconstruction)}


def test_a_protocol_names_its_missing_inputs_and_the_format_it_needs(tiny_scene, tmp_path):
    protocol = Protocol("toy", "a toy", "mesh", _score, {"gt": "toy.gt", "plane": "toy.plane"}, formats=("dtu",),
                        unit="mm")
    inputs = EvalInputs(tiny_scene, tmp_path / "mesh.ply", tmp_path / "m.json", gt=tmp_path / "gt.ply")
    with pytest.raises(Eve3dError, match=r"the toy protocol needs plane \(eve3d evaluate --plane\)"):
        protocol.run(inputs)
    inputs.plane = tmp_path / "plane.mat"
    with pytest.raises(Eve3dError, match="the toy protocol needs a dtu dataset, this one is colmap"):
        protocol.run(inputs)
    anywhere = Protocol("toy", "a toy", "mesh", _score, unit="mm")
    metrics = anywhere.run(inputs)
    assert metrics["protocol"] == "toy" and metrics["unit"] == "mm" and metrics["fscore"] == 0.5
    assert metrics["evaluator"] == f"{__name__}._score" and metrics["versions"]["eve3d"]
    assert anywhere.check_ground_truth(inputs) == {"protocol": "toy"}  # nothing to check


def test_the_registry_is_what_the_protocol_modules_declare():
    modules = [importlib.import_module(f"eve3d.evaluate.{m.name}") for m in pkgutil.iter_modules(evaluate.__path__)]
    declared = [m.PROTOCOL for m in modules if hasattr(m, "PROTOCOL")]
    assert list(evaluate.PROTOCOLS.values()) == declared and len(declared) == len({p.name for p in declared}) == 4
    assert set(evaluate.DEFAULT_PROTOCOL) == {f.name for f in formats()}  # every layout has its protocol
    assert evaluate.GROUND_TRUTH_INPUTS["gt"] == {"dtu": "dtu.stl", "synthetic": "gt_mesh"}
