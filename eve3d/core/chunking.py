"""Work that goes through every point of a large cloud (projections, ray casts, tree
queries, surface samples) done a chunk of points at a time, so that its temporaries are a
chunk's, not the cloud's: ten million points projected at once held about 1 GB of them."""
from __future__ import annotations

from collections.abc import Iterator

CHUNK = 1_000_000
"""Points per chunk."""


def chunks(n: int, size: int | None = None) -> Iterator[slice]:
    """Slices of ``range(n)`` of ``size`` (default :data:`CHUNK`, read at the call), in order."""
    size = size or CHUNK
    for start in range(0, n, size):
        yield slice(start, min(start + size, n))
