"""Shared damage for MCAP tests: a log with one chunk zeroed in its middle, as a torn write or a bad
sector leaves it (design §5: the reader skips the chunk and counts what it lost)."""

from mcap.reader import make_reader


def corrupt_middle_chunk(src, dst):
    """Write to ``dst`` a copy of the MCAP ``src`` with 64 bytes zeroed inside its middle chunk."""
    with open(src, "rb") as f:
        chunks = sorted((c.chunk_start_offset, c.chunk_length) for c in make_reader(f).get_summary().chunk_indexes)
    start, length = chunks[len(chunks) // 2]
    data = bytearray(src.read_bytes())
    data[start + length // 2:start + length // 2 + 64] = bytes(64)
    dst.write_bytes(bytes(data))
