"""eve3d.report.sheets: the scene sheets' panels and error maps."""
import numpy as np

from eve3d.evaluate.common import write_error_maps
from eve3d.core.fileio import write_image
from eve3d.core.layout import Layout
from eve3d.report.sheets import ERROR_MAP_BACKGROUND, ERROR_MAP_PIXELS, error_map, scene_panels


def test_error_map_is_seen_from_above_with_y_up(tmp_path):
    """A white floor of 2 × 1 under a dark roof over its top-left corner: each pixel shows
    its highest point, so the corner is dark; the longest side spans ERROR_MAP_PIXELS; +y
    is up, as on a plot; a pixel without a point shows the background."""
    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform((0, 0), (2, 1), (100_000, 2)), np.zeros(100_000)]
    roof = np.c_[rng.uniform((0, 0.75), (0.5, 1), (60_000, 2)), np.ones(60_000)]  # 34 a pixel
    points, top = np.r_[floor, roof], 1.0
    distances = np.r_[np.zeros(len(floor)), np.full(len(roof), top)]
    write_error_maps(tmp_path, points, distances, points, distances, top)
    image = error_map(tmp_path / "precision.ply")
    height, width, _ = image.shape
    assert width == ERROR_MAP_PIXELS and abs(height - ERROR_MAP_PIXELS // 2) <= 1
    shown = (image != ERROR_MAP_BACKGROUND).any(-1)
    assert 0.7 < shown.mean() < 1  # 3.5 floor points a pixel leave a few empty
    corner = image[: height // 4 - 2, : width // 4 - 2][shown[: height // 4 - 2, : width // 4 - 2]]
    rest = image[height // 4 + 2:][shown[height // 4 + 2:]]
    assert len(corner) > 100 and np.all(corner == corner[0]) and corner[0].max() < 0.1  # the roof hides the floor
    assert len(rest) > 1000 and np.all(rest == 1)  # below it, the white floor


def test_a_sheet_shows_the_environment_and_the_rendered_alpha(tmp_path):
    """What was taken for sky: the method's environment map and the first view's rendered
    alpha (the exported depth's confidence) are panels when the method has them."""
    layout = Layout(tmp_path / "results")
    photo = tmp_path / "images" / "000.png"
    for path in (photo, layout.depth("s", "pgsr") / "000.confidence.png", layout.method("s", "pgsr") / "environment.png"):
        write_image(path, np.zeros((4, 8, 3), np.uint8))
    titles = [title for title, _ in scene_panels(layout, "s", "pgsr", photo, "sgbm")]
    assert titles == ["photo", "rendered alpha (black: the environment's, not fused)",
                      "environment at infinity (azimuth across, zenith on top)"]
