"""Pure-Python LZF decompression, for PCD files stored as ``DATA binary_compressed``.

LZF (used by PCL) is a byte-oriented LZ77 variant: a control byte below 32 starts a literal run
of ``ctrl + 1`` bytes; otherwise its top 3 bits give a match length (7 = read one more length
byte) and its low 5 bits with the next byte a back-reference distance. The loop runs per token,
not per byte, so a few MB decompress in well under a second.
"""

from __future__ import annotations


class LZFError(ValueError):
    """The compressed stream is corrupt or does not decompress to the expected size."""


def decompress(data: bytes, expected_size: int) -> bytes:
    """Decompress an LZF block whose uncompressed size is known (PCD stores it).

    Parameters
    ----------
    data : bytes
        Compressed stream.
    expected_size : int
        Uncompressed size in bytes.

    Returns
    -------
    bytes
        Exactly ``expected_size`` bytes.

    Raises
    ------
    LZFError
        On a corrupt stream (reference before the start, overrun) or a size mismatch.
    """
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        ctrl = data[i]
        i += 1
        if ctrl < 32:
            length = ctrl + 1
            if i + length > n:
                raise LZFError("literal run overruns the compressed data")
            out += data[i : i + length]
            i += length
            continue
        length = ctrl >> 5
        if length == 7:
            if i >= n:
                raise LZFError("truncated match length")
            length += data[i]
            i += 1
        if i >= n:
            raise LZFError("truncated back-reference")
        ref = len(out) - ((ctrl & 0x1F) << 8) - data[i] - 1
        i += 1
        length += 2
        if ref < 0:
            raise LZFError("back-reference before the start of the data")
        distance = len(out) - ref
        if distance >= length:
            out += out[ref : ref + length]
        else:  # overlapping copy: the pattern of `distance` bytes repeats
            pattern = bytes(out[ref:])
            reps, rest = divmod(length, distance)
            out += pattern * reps + pattern[:rest]
        if len(out) > expected_size:
            raise LZFError(f"decompresses to more than the expected {expected_size} bytes")
    if len(out) != expected_size:
        raise LZFError(f"decompressed to {len(out)} bytes, expected {expected_size}")
    return bytes(out)
