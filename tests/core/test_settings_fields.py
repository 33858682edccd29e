"""eve3d.core.settings_fields: settings read from a config section, checked and converted, errors naming the key."""
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.settings import JointSettings, MeshSettings, PretrainSettings
from eve3d.core.settings_fields import from_mapping, pick
from eve3d.core.settings_stereo import BaselineSettings, StereoSettings


def test_unknown_or_mistyped_setting_is_named():
    with pytest.raises(Exception, match="joint.densify: unknown key.*grow_grad"):
        from_mapping(JointSettings, {"densify": {"grow_grad": 1}}, "joint")
    with pytest.raises(Exception, match="joint.iterations: expected an integer ≥ 0, got 'many'"):
        from_mapping(JointSettings, {"iterations": "many"}, "joint")


def test_errors_name_the_full_key_path_and_what_is_expected():
    with pytest.raises(Eve3dError, match=r"^stereo\.mv_views: expected an integer ≥ 1, got 0$"):
        from_mapping(StereoSettings, {"mv_views": 0}, "stereo")
    with pytest.raises(Eve3dError, match=r"^stereo\.mv_views: expected at most stereo\.mv_neighbours \(4\), got 5$"):
        from_mapping(StereoSettings, {"mv_views": 5}, "stereo")
    with pytest.raises(Eve3dError, match=r"^joint\.densify\.refine_every: expected an integer ≥ 1, got 0$"):
        from_mapping(JointSettings, {"densify": {"refine_every": 0}}, "joint")
    with pytest.raises(Eve3dError, match=r"^joint\.densify: unknown key\(s\) refine_evry \(known: .*refine_every"):
        from_mapping(JointSettings, {"densify": {"refine_evry": 10}}, "joint")
    with pytest.raises(Eve3dError, match=r"^stereo\.onnx\.layout: expected one of NCHW, NHWC, got 'CHW'$"):
        from_mapping(StereoSettings, {"onnx": {"layout": "CHW"}}, "stereo")
    with pytest.raises(Eve3dError, match=r"^mesh\.voxel: expected a number > 0, got -0\.5$"):
        from_mapping(MeshSettings, {"voxel": -0.5}, "mesh")
    with pytest.raises(Eve3dError, match=r"^joint\.depth: expected one of depth, depth_expected, got 'mesh'$"):
        JointSettings(depth="mesh")  # a direct call is checked too
    with pytest.raises(Eve3dError, match=r"^pretrain\.equalize"):
        from_mapping(PretrainSettings, {"equalize": 0.5}, "pretrain")


def test_values_are_converted_to_the_declared_kind():
    s = from_mapping(PretrainSettings, {"iterations": 10.0, "reinit_at": [], "resolution": 1,
                                        "lr": {"means": 1e-4}, "background": [1, 1, 1]}, "pretrain")
    assert s.iterations == 10 and type(s.iterations) is int and type(s.resolution) is float
    assert s.reinit_at == () and s.background == (1, 1, 1) and s.lr.means == 1e-4
    assert from_mapping(MeshSettings, {"voxel": None, "largest_cluster": None}, "mesh") == MeshSettings()
    with pytest.raises(Eve3dError, match=r"^pretrain\.iterations: expected an integer ≥ 0, got 10\.5$"):
        from_mapping(PretrainSettings, {"iterations": 10.5}, "pretrain")
    with pytest.raises(Eve3dError, match=r"^mesh\.largest_cluster: expected true or false, got 'yes'$"):
        from_mapping(MeshSettings, {"largest_cluster": "yes"}, "mesh")


def test_a_stage_reads_its_part_of_a_section():
    stereo = from_mapping(StereoSettings, {"baseline": "radius", "sgm_mode": "3way", "mv_views": 2}, "stereo")
    assert pick(BaselineSettings, stereo) == BaselineSettings(baseline="radius")
    assert stereo.sgm_mode == "3way" and stereo.mv_views == 2 and stereo.backend == "sgbm"
