"""The network's probabilities class by class, for the learned vote's sums and entropy.

The vote sums every point's probabilities per segment and per cell and takes every point's
entropy. On an (N, C) array each of these reads one class as a strided column, or reduces rows
of a dozen values, which is slow; one transposed copy, made a block of rows at a time, lets
them read contiguous rows. Every result is the one the row-major code gives, to the bit: the
sums add the same values in the same order (``np.bincount``), and the entropy's row sum adds a
row's terms in the order numpy's own reduction does (checked once per class count against
numpy; where it differs the row-major reduction is used).

A class the network gives exactly +0.0 at every point (one it rules out for the scan, see
:mod:`jointseg.network.presence`) sums to +0.0 in every unit and adds 0 * log(1e-6) = -0.0 to
every entropy: neither is computed point by point.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache

import numpy as np

#: Rows transposed (and entropies taken) at once: a block's float64 copies stay in the cache.
BLOCK = 1 << 13
#: numpy reduces a row of at most this many values as one pairwise block (its PW_BLOCKSIZE).
PAIRWISE_BLOCK = 128


@dataclass(frozen=True)
class ClassColumns:
    """The probabilities (N, C) as a (C, N) array in their own dtype.

    Attributes
    ----------
    values : ndarray of shape (C, N)
    live : ndarray of shape (C,), bool
        Classes with some value other than +0.0.
    """

    values: np.ndarray
    live: np.ndarray

    @classmethod
    def of(cls, probs: np.ndarray) -> ClassColumns:
        """``probs`` (N, C) copied a block of rows at a time (a whole-array transposed copy
        walks memory with a large stride)."""
        n, n_classes = probs.shape
        values = np.empty((n_classes, n), dtype=probs.dtype)
        for start in range(0, n, BLOCK):
            values[:, start : start + BLOCK] = probs[start : start + BLOCK].T
        bits = values.view(np.dtype(f"u{values.itemsize}"))
        live = bits.max(axis=1) != 0 if n else np.zeros(n_classes, dtype=bool)
        return cls(values, live)

    def sums(self, unit: np.ndarray, n_units: int) -> np.ndarray:
        """Per unit, the sum of each class's probabilities (U, C), float64: the
        :func:`jointseg.grouping.group_sums` of the row-major array, to the bit."""
        out = np.zeros((n_units, len(self.values)))
        weights = np.empty(self.values.shape[1])  # one float64 copy, reused class by class
        for c in np.flatnonzero(self.live):
            np.copyto(weights, self.values[c])
            out[:, c] = np.bincount(unit, weights=weights, minlength=n_units)
        return out

    def entropy(self) -> np.ndarray:
        """Entropy of every point divided by log C:
        :func:`jointseg.fusion.offers.normalised_entropy` of the row-major array, to the
        bit."""
        n_classes, n = self.values.shape
        runs = _runs(self.live)
        out = np.empty(n)
        block_buf = np.empty((n_classes, min(n, BLOCK)))
        terms_buf = np.empty_like(block_buf)
        for start in range(0, n, BLOCK):
            width = min(BLOCK, n - start)
            block, terms = block_buf[:, :width], terms_buf[:, :width]
            np.copyto(block, self.values[:, start : start + width])
            for lo, hi, live in runs:
                if not live:
                    terms[lo:hi] = -0.0  # 0 * log(0 + 1e-6)
                    continue
                np.add(block[lo:hi], 1e-6, out=terms[lo:hi])
                np.log(terms[lo:hi], out=terms[lo:hi])
                terms[lo:hi] *= block[lo:hi]
            np.negative(_row_sums(list(terms)), out=out[start : start + width])
        return out / np.log(n_classes)


def _runs(flags: np.ndarray) -> list[tuple[int, int, bool]]:
    """Runs of equal ``flags``: (start, stop, flag)."""
    if len(flags) == 0:
        return []
    edges = [0, *(np.flatnonzero(np.diff(flags.astype(np.int8))) + 1).tolist(), len(flags)]
    return [(lo, hi, bool(flags[lo])) for lo, hi in zip(edges[:-1], edges[1:], strict=True)]


def rows_entropy(probs: np.ndarray) -> np.ndarray:
    """Entropy of every row of ``probs`` (N, C) divided by log C, a block of rows at a time
    (float64 copies of at most BLOCK rows)."""
    n, n_classes = probs.shape
    out = np.empty(n)
    for start in range(0, n, BLOCK):
        block = np.asarray(probs[start : start + BLOCK].T, dtype=np.float64, order="C")
        terms = block + 1e-6
        np.log(terms, out=terms)
        terms *= block
        out[start : start + BLOCK] = -_row_sums(list(terms))
    return out / np.log(n_classes)


def _row_sums(rows: Sequence[np.ndarray]) -> np.ndarray:
    """Elementwise sum of the C arrays ``rows``, as ``ndarray.sum(axis=1)`` sums a C-contiguous
    array whose rows' values they are (:func:`_pairwise_rows` where it matches numpy)."""
    if _pairwise_matches_numpy(len(rows)):
        return _pairwise_rows(rows)
    return np.ascontiguousarray(np.stack(rows).T).sum(axis=1)


def _pairwise_rows(terms: Sequence[np.ndarray]) -> np.ndarray:
    """Elementwise sum of the C arrays ``terms`` in the order numpy's pairwise sum adds a
    contiguous row of C values (C <= PAIRWISE_BLOCK): eight running sums joined as a tree,
    then the rest one by one; the reduction starts from add's identity, +0.0."""
    n = len(terms)
    if n < 8:
        out = terms[0].copy()
        for row in terms[1:]:
            out += row
    else:
        tail = n - n % 8
        acc = [terms[j].copy() for j in range(8)]
        for i in range(8, tail, 8):
            for j in range(8):
                acc[j] += terms[i + j]
        out = (acc[0] + acc[1]) + (acc[2] + acc[3])
        out += (acc[4] + acc[5]) + (acc[6] + acc[7])
        for row in terms[tail:]:
            out += row
    out += 0.0  # -0.0 (every term -0.0) becomes +0.0, as from the identity
    return out


@cache
def _pairwise_matches_numpy(n_classes: int) -> bool:
    """Whether :func:`_pairwise_rows` sums as ``ndarray.sum(axis=1)`` does in this numpy, to
    the sign of a zero."""
    if not 1 <= n_classes <= PAIRWISE_BLOCK:
        return False
    rng = np.random.default_rng(n_classes)
    rows = rng.random((257, n_classes)) * 10.0 ** rng.integers(-8, 8, (257, n_classes))
    rows[0] = -0.0
    rows[1, ::2] = -0.0
    ours, numpys = _pairwise_rows(list(np.ascontiguousarray(rows.T))), rows.sum(axis=1)
    return bool(np.array_equal(ours, numpys) and (np.signbit(ours) == np.signbit(numpys)).all())
