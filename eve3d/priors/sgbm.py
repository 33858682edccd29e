"""The ``sgbm`` stereo backend: OpenCV's StereoSGBM, its left–right check against
opencv-contrib's right matcher and optional WLS filtering (``ximgproc``), gated by texture.
The default: no weights (its speed: docs/results.md, "Figures behind the code's choices")."""
from __future__ import annotations

import numpy as np

from eve3d.core.settings_fields import pick
from eve3d.core.settings_stereo import SGM_MODES, SgbmSettings, StereoSettings
from eve3d.priors.matching import left_right_consistent, local_std


def _matcher(min_disparity: int, num_disparities: int, settings: SgbmSettings):
    import cv2

    b = settings.block_size
    return cv2.StereoSGBM_create(minDisparity=min_disparity, numDisparities=num_disparities, blockSize=b, P1=8 * 3 * b * b,
                                 P2=32 * 3 * b * b, disp12MaxDiff=-1, uniquenessRatio=settings.uniqueness,
                                 speckleWindowSize=settings.speckle_window, speckleRange=settings.speckle_range,
                                 mode=getattr(cv2, SGM_MODES[settings.sgm_mode]))


def _right_matcher(sgbm):
    """The matcher of the right image against the left: ximgproc's ``createRightMatcher`` where
    opencv-contrib is installed, else the SGBM that contrib builds (the mirrored range, no
    uniqueness or speckle filter), since a GPU machine may have plain OpenCV only."""
    import cv2

    if hasattr(cv2, "ximgproc"):
        return cv2.ximgproc.createRightMatcher(sgbm)
    return cv2.StereoSGBM_create(
        minDisparity=-(sgbm.getMinDisparity() + sgbm.getNumDisparities()) + 1, numDisparities=sgbm.getNumDisparities(),
        blockSize=sgbm.getBlockSize(), P1=sgbm.getP1(), P2=sgbm.getP2(), disp12MaxDiff=1000000,
        preFilterCap=sgbm.getPreFilterCap(), uniquenessRatio=0, speckleWindowSize=0, mode=sgbm.getMode())


def sgbm_disparity(left: np.ndarray, right: np.ndarray, max_disparity: float, settings: SgbmSettings | None = None,
                   min_disparity: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Disparity of the left image (float32, px; 0 where invalid) and its confidence (float32
    in [0, 1]): the left–right check against ximgproc's right matcher, or the WLS filter's
    confidence map, in both cases gated by texture. Searched from ``min_disparity`` to at
    least ``max_disparity`` (the range rounded up to a multiple of 16 px)."""
    import cv2

    settings = settings or SgbmSettings()
    low = int(np.floor(max(min_disparity, 0)))
    num = int(np.ceil(max(max_disparity - low, 16) / 16.0)) * 16
    sgbm = _matcher(low, num, settings)
    right_matcher = _right_matcher(sgbm)
    raw_l, raw_r = sgbm.compute(left, right), right_matcher.compute(right, left)  # 1/16 px; right ≤ 0
    textured = local_std(left, settings.block_size) >= settings.min_texture
    if settings.wls:
        wls = cv2.ximgproc.createDisparityWLSFilter(sgbm)
        wls.setLambda(settings.wls_lambda)
        wls.setSigmaColor(settings.wls_sigma)
        disp = wls.filter(raw_l, left, disparity_map_right=raw_r).astype(np.float32) / 16.0
        confidence = wls.getConfidenceMap().astype(np.float32) / 255.0
    else:
        # Invalid pixels hold minDisparity − 1 (in 1/16 px), which is positive once the range starts above 1.
        def in_range(raw):
            return np.where((raw >= 16 * low) & (raw < 16 * (low + num)), raw / 16.0, 0)

        disp = in_range(raw_l.astype(np.float32))
        confidence = left_right_consistent(disp, in_range(-raw_r.astype(np.float32)), settings.lr_threshold)
    return np.maximum(disp, 0).astype(np.float32), np.where(textured & (disp > 0), confidence, 0).astype(np.float32)


class SgbmStereo:
    """``matcher(left, right, (min, max))`` for :func:`eve3d.stereo.stereo_priors`: the
    range searched from its start to at least its end."""

    def __init__(self, settings: SgbmSettings | None = None):
        self.settings = settings or SgbmSettings()

    def __call__(self, left: np.ndarray, right: np.ndarray, search: tuple[float, float]
                 ) -> tuple[np.ndarray, np.ndarray]:
        return sgbm_disparity(left, right, search[1], self.settings, search[0])


def matcher(settings: StereoSettings) -> SgbmStereo:
    """The ``sgbm`` row of :data:`eve3d.core.settings_stereo.PRIOR_BACKENDS`."""
    return SgbmStereo(pick(SgbmSettings, settings))
