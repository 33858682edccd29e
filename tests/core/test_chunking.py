"""eve3d.core.chunking: a range cut into chunks."""
from eve3d.core import chunking
from eve3d.core.chunking import chunks


def test_chunks_cover_the_range_in_order_and_read_the_size_at_the_call(monkeypatch):
    assert list(chunks(10, 4)) == [slice(0, 4), slice(4, 8), slice(8, 10)]
    assert list(chunks(8, 4)) == [slice(0, 4), slice(4, 8)]
    assert list(chunks(0, 4)) == []
    assert list(chunks(3)) == [slice(0, 3)]  # the default: a million points a chunk
    monkeypatch.setattr(chunking, "CHUNK", 2)
    assert list(chunks(5)) == [slice(0, 2), slice(2, 4), slice(4, 5)]
