"""eve3d: surface reconstruction with Gaussian Splatting and learnable stereo depth priors."""
import sys
import types

__version__ = "0.1.0"


def _open3d_without_its_plotly_viewer() -> None:
    """open3d imports its notebook viewer (``open3d.visualization.draw_plotly``: dash, plotly,
    IPython) at ``import open3d``, most of a second in every job that meshes, scores or reads
    a COLMAP model (docs/results.md, "Figures behind the code's choices"). eve3d never opens it,
    so that one module is a placeholder that says so when called; the rest of open3d is as
    shipped. Set once here, before any module of the package imports open3d."""
    if "open3d" in sys.modules:  # imported already, viewer and all
        return
    name = "open3d.visualization.draw_plotly"
    viewer = types.ModuleType(name, "placeholder: eve3d does not load open3d's plotly viewer (eve3d/__init__.py)")

    def unavailable(*args, **kwargs):
        raise ImportError(f"{name} is not loaded under eve3d (eve3d/__init__.py); eve3d's own 3D views are the report's")

    viewer.get_plotly_fig = viewer.draw_plotly = viewer.draw_plotly_server = unavailable
    sys.modules[name] = viewer


_open3d_without_its_plotly_viewer()
