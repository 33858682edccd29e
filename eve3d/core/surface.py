"""Seeded surface sampling shared by the synthetic generator and the evaluator."""
from __future__ import annotations

import numpy as np

from eve3d.core.chunking import chunks


def sample_surface(vertices: np.ndarray, triangles: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` points uniformly distributed over the area of a triangle mesh. The areas
    and the points are computed a chunk of triangles or points at a time
    (:mod:`eve3d.core.chunking`; the random draws all at once, so the samples do not depend on it)."""
    v, f = np.asarray(vertices, dtype=np.float64), np.asarray(triangles)
    area = np.empty(len(f))
    for part in chunks(len(f)):
        a, b, c = (v[f[part, k]] for k in range(3))
        area[part] = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    if area.sum() <= 0:
        return np.zeros((0, 3))
    pick = rng.choice(len(f), size=count, p=area / area.sum())
    r1, r2 = rng.random(count), rng.random(count)
    out = np.empty((count, 3))
    for part in chunks(count):
        s, r, corners = np.sqrt(r1[part]), r2[part], f[pick[part]]
        a, b, c = (v[corners[:, k]] for k in range(3))
        out[part] = (1 - s)[:, None] * a + (s * (1 - r))[:, None] * b + (s * r)[:, None] * c
    return out
