"""Neighbour views for the multi-view losses (DESIGN §3).

Score s(i, j) = Σ_X η(θ_ij(X)) over the sparse points X both views observe, θ the
triangulation angle in degrees, η(θ) = exp(−(θ−5)²/2) for θ ≤ 5 and exp(−(θ−5)²/200)
above: views that see much of the same surface at a useful baseline score high.
"""
from __future__ import annotations

import numpy as np

from eve3d.core.scene import Scene


def triangulation_score(theta_deg: np.ndarray) -> np.ndarray:
    """η(θ) of DESIGN §3."""
    return np.where(theta_deg <= 5, np.exp(-(theta_deg - 5) ** 2 / 2), np.exp(-(theta_deg - 5) ** 2 / 200))


def neighbour_scores(scene: Scene) -> np.ndarray:
    """(V, V) symmetric scores s(i, j) from the shared sparse points (zero diagonal)."""
    n = len(scene.cameras)
    scores = np.zeros((n, n))
    if scene.points is None or scene.point_views is None:
        return scores
    centres = np.array([c.center for c in scene.cameras])
    for point, views in zip(scene.points, scene.point_views):
        views = np.asarray(views)
        if len(views) < 2:
            continue
        rays = point - centres[views]
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        theta = np.degrees(np.arccos(np.clip(rays @ rays.T, -1, 1)))
        scores[np.ix_(views, views)] += triangulation_score(theta)
    np.fill_diagonal(scores, 0)
    return scores


def select_neighbours(scene: Scene, k: int) -> list[list[int]]:
    """The ``k`` best neighbours of every view. Without sparse points, the nearest camera
    centres among views whose optical axes are within 60° stand in."""
    scores = neighbour_scores(scene)
    if not scores.any():
        centres = np.array([c.center for c in scene.cameras])
        axes = np.array([c.R[2] for c in scene.cameras])
        dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
        dist[axes @ axes.T < np.cos(np.radians(60))] = np.inf
        np.fill_diagonal(dist, np.inf)
        scores = -dist
    out = []
    for i in range(len(scene.cameras)):
        order = [j for j in np.argsort(-scores[i], kind="stable") if j != i and np.isfinite(scores[i, j])]
        out.append([int(j) for j in order[:k]])
    return out
