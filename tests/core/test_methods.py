"""eve3d.core.methods: the method registry; variants are config, and train as the method they spell out."""
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.methods import REGISTRY, methods
from eve3d.joint import train_joint
from tests.helpers import joint_settings


def test_variants_add_methods_and_change_registered_ones():
    known = methods({"pgsr-no-mv": {"method": "pgsr", "geo_weight": 0, "ncc_weight": 0},
                     "pgsr-no-mv-dn": {"method": "pgsr-no-mv", "dn_weight": 0},
                     "3dgs": {"densify": {"grow_grad2d": 0.0004}}})
    assert set(REGISTRY) < set(known)
    assert known["pgsr-no-mv-dn"].settings == {"geo_weight": 0, "ncc_weight": 0, "dn_weight": 0}
    # a registered name's variant changes its settings key by key
    assert known["3dgs"].settings["densify"] == {"absgrad": False, "grow_grad2d": 0.0004}
    assert known["3dgs"].settings["depth"] == "depth_expected"
    assert REGISTRY["3dgs"].settings["densify"] == {"absgrad": False}  # the registry itself is untouched


@pytest.mark.parametrize("variants, message", [
    ({"mine": {"lba_weight": 0}}, "variants.mine: say which method"),
    ({"mine": {"method": "pgsrr"}}, "variants.mine.method: unknown method 'pgsrr'"),
    ({"a": {"method": "b"}, "b": {"method": "a"}}, "cycle"),
    ({"tsdf2": {"method": "stereo-tsdf", "dn_weight": 0}}, "not trained"),
])
def test_bad_variant_is_named(variants, message):
    with pytest.raises(Eve3dError, match=message):
        methods(variants)


def test_a_variant_in_config_trains_exactly_like_the_registered_method(tiny_scene, tmp_path, one_thread):
    """3dgs spelled out as a variant of pgsr gives the byte-identical model: a method is
    its settings and nothing else (the refactor that made the registry was checked the
    same way against the code before it: single-threaded pgsr and 3dgs runs of 300
    iterations wrote byte-identical point_cloud.ply files)."""
    spelled = methods({"my-3dgs": {"method": "pgsr", **REGISTRY["3dgs"].settings}})["my-3dgs"]
    for name, m in (("3dgs", REGISTRY["3dgs"]), ("my-3dgs", spelled)):
        train_joint(tiny_scene, tmp_path / name, joint_settings(iterations=40, **_overrides(m.settings)))
    assert (tmp_path / "3dgs/point_cloud.ply").read_bytes() == (tmp_path / "my-3dgs/point_cloud.ply").read_bytes()


def _overrides(settings: dict) -> dict:
    from dataclasses import replace

    from eve3d.core.settings import DensifySettings

    out = dict(settings)
    if "densify" in out:
        base = joint_settings().densify
        out["densify"] = replace(base, **out["densify"]) if isinstance(base, DensifySettings) else out["densify"]
    return out
