"""Readers that turn every supported dataset layout into the one ``Scene``."""
from eve3d.core.io.colmap import find_colmap_model
from eve3d.core.io.loader import has_poses, load_scene

__all__ = ["find_colmap_model", "has_poses", "load_scene"]
