"""eve3d/__init__.py: what importing the package does to the libraries it uses."""
import subprocess
import sys

from tests.helpers import REPO


def test_open3d_loads_without_its_plotly_viewer_and_the_rest_of_it_works():
    """After ``import eve3d``, ``import open3d`` loads no dash, plotly or IPython; the viewer
    says why it is missing, and what eve3d uses of ``open3d.visualization`` (the T&T crop
    volume's reader) and of the ray casting is there."""
    code = """if True:
        import sys
        import eve3d, numpy as np, open3d as o3d
        print(sorted(m for m in ("dash", "plotly", "IPython") if m in sys.modules))
        print(callable(o3d.visualization.read_selection_polygon_volume))
        try:
            o3d.visualization.draw_plotly([])
        except ImportError as e:
            print(e)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(o3d.geometry.TriangleMesh.create_box()))
        rays = o3d.core.Tensor(np.array([[0.5, 0.5, -1, 0, 0, 1]], np.float32))
        print(scene.cast_rays(rays)["t_hit"].numpy()[0])
    """
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    loaded, reader, missing, hit = r.stdout.splitlines()
    assert loaded == "[]" and reader == "True"
    assert "draw_plotly is not loaded under eve3d" in missing
    assert abs(float(hit) - 1.0) < 1e-6  # the box's bottom face, one unit along the ray (float32)
