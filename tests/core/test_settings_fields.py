"""eve3d.core.settings_fields: settings read from a config section, checked and converted, errors naming the key."""
import pytest

from eve3d.core.settings import JointSettings
from eve3d.core.settings_fields import from_mapping


def test_unknown_or_mistyped_setting_is_named():
    with pytest.raises(Exception, match="joint.densify: unknown key.*grow_grad"):
        from_mapping(JointSettings, {"densify": {"grow_grad": 1}}, "joint")
    with pytest.raises(Exception, match="joint.iterations: expected an integer ≥ 0, got 'many'"):
        from_mapping(JointSettings, {"iterations": "many"}, "joint")
