"""eve3d.tools.keydoc: config/README.md's key tables, generated from the settings."""


def test_config_readme_tables_are_generated_from_the_settings():
    """config/README.md's key tables are what `python -m eve3d.tools.keydoc` writes, and every key
    has a docstring to fill its row and its CLI help."""
    from eve3d.core.settings_fields import keys, sections_of
    from eve3d.tools.keydoc import README, TABLES, with_tables

    text = README.read_text()
    assert with_tables(text) == text, "config/README.md is out of date: run `python -m eve3d.tools.keydoc`"
    for _, cls in TABLES:
        for c in [cls, *sections_of(cls).values()]:
            assert [k.name for k in keys(c) if not k.doc] == [], c.__name__
    assert "| `mesh.voxel`" not in text and "| `voxel` | `null` | a number > 0 or null |" in text
