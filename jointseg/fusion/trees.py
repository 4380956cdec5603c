"""The learned vote's tree ensemble evaluated fast, to the bit as a walk of every tree for every
row would give.

A big scan makes a few hundred thousand offers and the shipped model has a hundred trees, so a
walk per tree (index subsets sent down its nodes) was the fusion stage's largest cost. Three
things cut it, none of which changes a result:

- A feature that is the same in every row (the scan's mean entropy, its disagreement, whether it
  has colour) decides its splits once: each tree keeps only the branches it takes, which leaves
  most trees a handful of split nodes.
- What is left of a tree is read as one integer per row whose bits are its remaining split
  tests, looked up in a table of its leaf values.
- Rows that share a *context* (the caller's promise: every feature equal except the ``varying``
  ones) take their context's splits once per context; rows whose varying features also fall
  between the same thresholds of every split are one row.

The leaf values are added tree by tree in the model's order, starting from its base, so every
sum rounds as the walk's does; equal rows get equal sums.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from jointseg.grouping import compact_ids

#: A tree left with more split nodes than this (once the constant features have decided theirs)
#: is walked node by node instead of read through a table of 2**bits leaf values.
MAX_TABLE_BITS = 14
#: Specialised ensembles kept per model (one per set of constant feature values seen; the tiles
#: of one scan share theirs).
PLANS_KEPT = 8


class TreeArrays(Protocol):
    """The arrays of a gradient-boosted ensemble
    (:class:`jointseg.fusion.tree_runtime.TreeEnsemble`): per tree, node 0 the root; a row goes
    left where ``x[feature] <= threshold``."""

    @property
    def base(self) -> float: ...
    @property
    def feature(self) -> list[np.ndarray]: ...
    @property
    def threshold(self) -> list[np.ndarray]: ...
    @property
    def left(self) -> list[np.ndarray]: ...
    @property
    def right(self) -> list[np.ndarray]: ...
    @property
    def value(self) -> list[np.ndarray]: ...
    @property
    def leaf(self) -> list[np.ndarray]: ...


def split_thresholds(trees: TreeArrays, n_features: int) -> list[np.ndarray]:
    """Per feature, the distinct thresholds its split nodes use, sorted (empty where none)."""
    inner = [~leaf for leaf in trees.leaf]
    feature = np.concatenate([f[i] for f, i in zip(trees.feature, inner, strict=True)] + [[]])
    threshold = np.concatenate([t[i] for t, i in zip(trees.threshold, inner, strict=True)] + [[]])
    feature = feature.astype(np.int64)
    return [np.unique(threshold[feature == f]) for f in range(n_features)]


@dataclass(frozen=True)
class Rows:
    """Which rows are evaluated: one per context, and one per distinct row within a context.

    Attributes
    ----------
    context_row : ndarray of shape (K,), int64
        A row of each context (its context features are every row's of that context).
    unique_row : ndarray of shape (U,), int64
        A row of each distinct row.
    unique_context : ndarray of shape (U,), int64 or None
        The context of each distinct row; None where the distinct rows are the contexts.
    inverse : ndarray of shape (M,), int64 or None
        The distinct row of every row; None where every row is its own.
    """

    context_row: np.ndarray
    unique_row: np.ndarray
    unique_context: np.ndarray | None
    inverse: np.ndarray | None

    @classmethod
    def each(cls, m: int) -> Rows:
        """Every row its own context."""
        every = np.arange(m)
        return cls(every, every, None, None)

    @classmethod
    def grouped(cls, x: np.ndarray, context: np.ndarray, cuts: dict[int, np.ndarray]) -> Rows:
        """Contexts as given; rows of one context are one where every varying feature (the
        keys of ``cuts``) has the same rank among that feature's split thresholds ``cuts[f]``
        (sorted), so that every split sends them the same way."""
        m = len(x)
        context = np.asarray(context, dtype=np.int64)
        context = context - context.min()
        code = np.zeros(m, dtype=np.int64)
        radix = 1
        limit = (1 << 62) // (int(context.max()) + 1)
        for f, thresholds in sorted(cuts.items()):
            if len(thresholds) == 0:
                continue
            if radix * (len(thresholds) + 1) > limit:  # no key fits: every row is evaluated
                _, ctx = compact_ids(context)
                context_row = np.empty(int(ctx.max()) + 1, dtype=np.int64)
                context_row[ctx] = np.arange(m)
                return cls(context_row, np.arange(m), ctx, None)
            code *= len(thresholds) + 1
            code += np.searchsorted(thresholds, x[:, f])
            radix *= len(thresholds) + 1
        key = context * radix + code if radix > 1 else context
        distinct, unique_row, inverse = _distinct(key)
        # the keys are sorted, so each context's distinct rows are consecutive
        ctx_of_key = distinct // radix
        first = np.ones(len(distinct), dtype=bool)
        first[1:] = ctx_of_key[1:] != ctx_of_key[:-1]
        unique_context = np.cumsum(first) - 1
        return cls(unique_row[first], unique_row, unique_context, inverse)


def _distinct(key: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sorted distinct values of ``key`` (non-negative), a row holding each and the
    distinct value of every row: ``np.unique``, but where the row numbers fit beside the keys
    in 63 bits one plain sort of both does (much faster than the arg-sort it takes)."""
    m = len(key)
    shift = max(int(m - 1).bit_length(), 1)
    if int(key.max()) >= 1 << (63 - shift):
        distinct, inverse = np.unique(key, return_inverse=True)
        inverse = inverse.reshape(-1)
        row = np.empty(len(distinct), dtype=np.int64)
        row[inverse] = np.arange(m)
        return distinct, row, inverse
    packed = key << shift
    packed |= np.arange(m)
    packed.sort()
    ordered = packed >> shift
    new = np.empty(m, dtype=bool)
    new[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    rows = packed & ((1 << shift) - 1)
    inverse = np.empty(m, dtype=np.int64)
    inverse[rows] = np.cumsum(new) - 1
    return ordered[new], rows[new], inverse


@dataclass(frozen=True)
class TreePlan:
    """One tree with the constant features' splits taken: its remaining split nodes (each a bit
    of a row's code, context nodes and varying-feature nodes apart) and the leaf value of every
    code; a tree with more than MAX_TABLE_BITS nodes left has no table and is walked."""

    tree: int
    context_nodes: list[tuple[int, float, int]]
    varying_nodes: list[tuple[int, float, int]]
    table: np.ndarray | None


def plan_tree(
    trees: TreeArrays, t: int, fixed: dict[int, float], varying: frozenset[int]
) -> TreePlan:
    """Tree ``t`` specialised to the constant feature values ``fixed``: its split nodes left,
    bit by bit, and (for at most MAX_TABLE_BITS of them) the leaf value of every code."""
    feature, threshold = trees.feature[t], trees.threshold[t]
    left, right, leaf, value = trees.left[t], trees.right[t], trees.leaf[t], trees.value[t]
    taken: dict[int, int] = {}  # a constant's split node -> the child it sends every row to
    bit: dict[int, int] = {}
    nodes: list[tuple[int, float, int]] = []
    stack = [0]
    while stack:
        node = stack.pop()
        if leaf[node]:
            continue
        f, thr = int(feature[node]), float(threshold[node])
        if f in fixed:
            taken[node] = int(left[node] if fixed[f] <= thr else right[node])
            stack.append(taken[node])
            continue
        bit[node] = len(nodes)
        nodes.append((f, thr, len(nodes)))
        stack += [int(right[node]), int(left[node])]
    context_nodes = [nd for nd in nodes if nd[0] not in varying]
    varying_nodes = [nd for nd in nodes if nd[0] in varying]
    if len(nodes) > MAX_TABLE_BITS:
        return TreePlan(t, context_nodes, varying_nodes, None)
    codes = np.arange(1 << len(nodes), dtype=np.int64)

    def table(node: int) -> np.ndarray:
        """Leaf value reached from ``node`` for every code."""
        while node in taken:
            node = taken[node]
        if leaf[node]:
            return np.full(len(codes), value[node], dtype=np.float64)
        goes_left = (codes >> bit[node]) & 1 == 1
        return np.where(goes_left, table(int(left[node])), table(int(right[node])))

    return TreePlan(t, context_nodes, varying_nodes, table(0))


def varying_cuts(plans: list[TreePlan]) -> dict[int, np.ndarray]:
    """Per varying feature, the sorted distinct thresholds of the plans' varying split nodes
    (the only ones a row's rank must keep apart); a tree that is walked needs all of its."""
    cuts: dict[int, set[float]] = {}
    for plan in plans:
        for f, thr, _ in plan.varying_nodes:
            cuts.setdefault(f, set()).add(thr)
    return {f: np.array(sorted(thresholds)) for f, thresholds in cuts.items()}


def _codes(columns: np.ndarray, nodes: list[tuple[int, float, int]], into: np.ndarray) -> None:
    """Add each node's bit (the row goes left) to the codes ``into``; ``columns`` (F, R)."""
    for f, thr, b in nodes:
        into |= (columns[f] <= thr).astype(np.int64) << b


def _walk(trees: TreeArrays, t: int, columns: np.ndarray) -> np.ndarray:
    """Leaf value of tree ``t`` for every row of ``columns`` (F, R): index subsets sent down its
    nodes (a tree too big for a table)."""
    feature, threshold = trees.feature[t], trees.threshold[t]
    out = np.empty(columns.shape[1])
    stack = [(0, np.arange(columns.shape[1]))]
    while stack:
        node, idx = stack.pop()
        if trees.leaf[t][node]:
            out[idx] = trees.value[t][node]
            continue
        go_left = columns[feature[node]][idx] <= threshold[node]
        stack.append((int(trees.left[t][node]), idx[go_left]))
        stack.append((int(trees.right[t][node]), idx[~go_left]))
    return out


def constant_features(x: np.ndarray, used: list[int]) -> dict[int, float]:
    """The features of ``used`` that have one value in every row of ``x`` (M, F), M > 0 (NaN
    never counts as one): a spread sample rules most features out at once."""
    out = {}
    step = max(1, len(x) // 64)
    for f in used:
        col = x[:, f]
        if (col[::step] != col[0]).any():
            continue
        lo, hi = col.min(), col.max()
        if lo == hi:
            out[f] = float(lo)
    return out


def raw_scores(
    trees: TreeArrays,
    x: np.ndarray,
    plans: list[TreePlan],
    rows: Rows,
) -> np.ndarray:
    """``base`` plus every tree's leaf value, added in the trees' order, for each distinct row
    of ``rows`` (see :class:`Rows`); ``plans`` from :func:`plan_tree` for the constants of
    ``x`` (M, F)."""
    each = rows.unique_context is None and rows.inverse is None
    context_cols = np.ascontiguousarray((x if each else x[rows.context_row]).T)
    varying_cols = None
    if rows.unique_context is not None:
        varying_cols = np.ascontiguousarray(x[rows.unique_row].T)
    raw = np.full(len(rows.unique_row), trees.base)
    for plan in plans:
        if plan.table is None:
            full = context_cols if varying_cols is None else varying_cols
            raw += _walk(trees, plan.tree, full)
            continue
        code = np.zeros(context_cols.shape[1], dtype=np.int64)
        _codes(context_cols, plan.context_nodes, code)
        if rows.unique_context is None or not plan.varying_nodes:
            values = plan.table[code]
            raw += values if rows.unique_context is None else values[rows.unique_context]
            continue
        assert varying_cols is not None
        code = code[rows.unique_context]
        _codes(varying_cols, plan.varying_nodes, code)
        raw += plan.table[code]
    return raw
