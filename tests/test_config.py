"""eve3d.config: a workflow config resolved (every section whole, the classes' defaults) and each scene's protocol."""
import dataclasses

import pytest
import yaml

from eve3d.core.errors import Eve3dError
from eve3d.core.settings import SECTIONS
from eve3d.core.settings_fields import from_mapping
from eve3d.core.settings_stereo import StereoSettings
from tests.helpers import REPO


def test_defaults_live_once_in_the_settings():
    """The schema holds no leaf default but the workflow's own keys (preset, results,
    training_jobs: no settings class reads them; methods' default depends on the protocol), and a resolved
    config carries every section whole, with the settings classes' defaults."""
    from eve3d.config import resolve_config
    from eve3d.core.settings_stereo import SGM_MODES, SgbmSettings

    schema = yaml.safe_load((REPO / "workflow/schemas/config.schema.yaml").read_text())

    def leaf_defaults(node, path=""):
        if isinstance(node, dict):
            if "default" in node and node["default"] != {}:
                yield path
            for key, value in node.items():
                yield from leaf_defaults(value, f"{path}.{key}")
        elif isinstance(node, list):
            for value in node:
                yield from leaf_defaults(value, path)

    assert sorted(leaf_defaults(schema)) == [".properties.preset", ".properties.results", ".properties.training_jobs"]
    config = resolve_config({"scenes": {"a": {"synthetic": {"kind": "object", "views": 8}}},
                             "stereo": {"sgm_mode": "3way"}})
    for section, cls in SECTIONS.items():
        assert set(config[section]) == {f.name for f in dataclasses.fields(cls)}, section
    assert config["stereo"]["sgm_mode"] == "3way" and config["stereo"]["block_size"] == SgbmSettings().block_size
    assert config["synthetic"]["views"] == 32 and config["mesh"]["coarsen"] == 5  # the class's, then the cpu preset's
    for mode in SGM_MODES:
        assert from_mapping(StereoSettings, {"sgm_mode": mode}, "stereo").sgm_mode == mode
    with pytest.raises(Eve3dError, match=r"scenes\.a\.synthetic\.views: expected an integer ≥ 2, got 1"):
        resolve_config({"scenes": {"a": {"synthetic": {"kind": "object", "views": 1}}}})
    with pytest.raises(Eve3dError, match=r"scenes\.a\.evaluate\.tau: expected a number > 0, got 0"):
        resolve_config({"scenes": {"a": {"synthetic": {"kind": "object"}, "evaluate": {"tau": 0}}}})


def test_protocol_defaults_and_requirements_are_named(tmp_path, object_dataset):
    from eve3d.config import scene_protocol

    assert scene_protocol("a", {"synthetic": {"kind": "object"}}).name == "synthetic"
    assert scene_protocol("a", {"path": str(object_dataset), "protocol": "nvs"}).name == "nvs"
    with pytest.raises(Eve3dError, match=r"scenes.a.protocol: unknown protocol 'chamfer'"):
        scene_protocol("a", {"path": str(object_dataset), "protocol": "chamfer"})
    # no ground truth of the format's protocol: held-out views; a protocol named without it: refused
    assert scene_protocol("b", {"path": str(object_dataset)}).name == "nvs"
    assert scene_protocol("b", {"path": str(object_dataset), "gt_mesh": "gt.ply"}).name == "synthetic"
    with pytest.raises(Eve3dError, match=r"scenes.b \(protocol synthetic\): give gt_mesh"):
        scene_protocol("b", {"path": str(object_dataset), "protocol": "synthetic"})
    with pytest.raises(Eve3dError, match=r"scenes.c \(protocol dtu\): .* is a colmap dataset, the protocol scores dtu"):
        scene_protocol("c", {"path": str(object_dataset), "protocol": "dtu"})
    with pytest.raises(Eve3dError, match="the protocol scores tnt datasets"):
        scene_protocol("d", {"path": str(object_dataset), "protocol": "tnt"})
    with pytest.raises(Eve3dError, match="has no poses, and SfM would pose it in a frame of its own"):
        scene_protocol("e", {"path": str(object_dataset / "images"), "gt_mesh": "gt.ply"})


def test_photos_train_eve3d_alone_unless_the_config_names_methods(object_dataset):
    """A scene scored on held-out photos trains eve3d alone by default, one with ground truth
    every method; methods named by the config or the scene win."""
    from eve3d.config import named_methods, resolve_config

    scenes = {"photos": {"path": str(object_dataset)}, "generated": {"synthetic": {"kind": "object"}},
              "with-gt": {"path": str(object_dataset), "gt_mesh": "gt.ply"}}
    config = resolve_config({"scenes": scenes})
    assert named_methods(config, "photos") == ["eve3d"]
    assert named_methods(config, "generated") == named_methods(config, "with-gt") == [
        "oracle", "stereo-tsdf", "pgsr", "eve3d"]
    config = resolve_config({"methods": ["pgsr", "eve3d"], "scenes": {**scenes, "own": {
        "path": str(object_dataset), "methods": ["pgsr"]}}})
    assert named_methods(config, "photos") == named_methods(config, "generated") == ["pgsr", "eve3d"]
    assert named_methods(config, "own") == ["pgsr"]
