"""The learned vote (beyond the paper): a point takes its segment's majority label only where a
small model, fitted on labelled rooms, says the change is more likely right than wrong.

A strong network on real scans is mostly right, and real segments mix objects (a board inside
its wall plane, clutter on a table), so eq. 7 overwrites correct minority labels; a weak network
on clean segments is the opposite case. Which case a point is in shows in a few numbers the
vote already has: the network's probability of its own label and of the segment's label at the
point, the segment's soft and hard shares of both, its size and mean entropy. A gradient-boosted
tree ensemble over these (``vote_model.json``, fitted by ``bench/fit_vote.py`` on real tuning
rooms and synthetic rooms together, never on the judging rooms) decides per point. The model is
plain JSON evaluated with numpy: no learning library is needed at run time.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from jointseg.exceptions import ConfigError

#: The model shipped with the library.
MODEL_PATH = Path(__file__).with_name("vote_model.json")
#: Names of the features, in the order the model expects them.
FEATURES = (
    "logit p(own)",
    "logit p(segment label)",
    "logit segment soft share of its label",
    "logit segment soft share of own label",
    "logit segment hard share of its label",
    "log10 segment share of the scan",
    "segment mean entropy",
    "point entropy",
)
#: Probabilities are clipped to [EPS, 1 - EPS] before the logit.
EPS = 1e-4


def _logit(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, EPS, 1 - EPS)
    return np.log(x / (1 - x))


def segment_label_sums(seg: np.ndarray, n_seg: int, weights: np.ndarray) -> np.ndarray:
    """Per-segment column sums of ``weights`` (N, C): shape (n_seg, C)."""
    return np.column_stack(
        [np.bincount(seg, weights=weights[:, c], minlength=n_seg) for c in range(weights.shape[1])]
    )


def vote_features(
    seg: np.ndarray, n_seg: int, labels: np.ndarray, probs: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The segment's soft-majority label of every point and the features of the points where it
    differs from the network's label.

    Parameters
    ----------
    seg : ndarray of shape (N,), int
        Segment 0..n_seg-1 of every point.
    n_seg : int
    labels : ndarray of shape (N,), int
        The network's labels.
    probs : ndarray of shape (N, C)
        The network's probabilities (rows sum to 1).

    Returns
    -------
    candidate : ndarray of shape (N,), int64
        The segment's label (largest summed probability) at every point.
    open_ : ndarray of shape (M,), int64
        Indices of the points whose label differs from ``candidate``.
    features : ndarray of shape (M, len(FEATURES)), float64
    """
    n, n_classes = probs.shape
    size = np.bincount(seg, minlength=n_seg).astype(np.float64)
    per = np.maximum(size, 1)[:, None]
    soft = segment_label_sums(seg, n_seg, probs) / per
    hard = (
        np.bincount(seg * n_classes + labels, minlength=n_seg * n_classes).reshape(n_seg, n_classes)
        / per
    )
    candidate = soft.argmax(axis=1)[seg]
    entropy = -(probs * np.log(probs + 1e-6)).sum(axis=1) / np.log(n_classes)
    mean_entropy = np.bincount(seg, weights=entropy, minlength=n_seg) / np.maximum(size, 1)
    open_ = np.flatnonzero(candidate != labels)
    s, own, cand = seg[open_], labels[open_], candidate[open_]
    features = np.column_stack(
        [
            _logit(probs[open_, own]),
            _logit(probs[open_, cand]),
            _logit(soft[s, cand]),
            _logit(soft[s, own]),
            _logit(hard[s, cand]),
            np.log10(size[s] / max(n, 1)),
            mean_entropy[s],
            entropy[open_],
        ]
    )
    return candidate.astype(np.int64), open_, features


@dataclass(frozen=True)
class TreeEnsemble:
    """Gradient-boosted binary trees: P(change is right) = sigmoid(base + sum of leaf values).

    Each tree is stored as flat arrays; node 0 is the root, a point goes left where
    ``x[feature] <= threshold``.
    """

    base: float
    feature: list[np.ndarray]
    threshold: list[np.ndarray]
    left: list[np.ndarray]
    right: list[np.ndarray]
    value: list[np.ndarray]
    leaf: list[np.ndarray]
    card: dict

    @classmethod
    def from_json(cls, path: Path) -> TreeEnsemble:
        """Read a model written by ``bench/fit_vote.py``."""
        try:
            body = json.loads(path.read_text())
            trees = body["trees"]
            if body["features"] != list(FEATURES):
                raise ConfigError(f"{path}: features {body['features']} are not {list(FEATURES)}")
            return cls(
                base=float(body["base"]),
                feature=[np.asarray(t["feature"], np.int64) for t in trees],
                threshold=[np.asarray(t["threshold"], np.float64) for t in trees],
                left=[np.asarray(t["left"], np.int64) for t in trees],
                right=[np.asarray(t["right"], np.int64) for t in trees],
                value=[np.asarray(t["value"], np.float64) for t in trees],
                leaf=[np.asarray(t["leaf"], bool) for t in trees],
                card=dict(body.get("card", {})),
            )
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"vote model {path}: {exc}") from exc

    def probability(self, x: np.ndarray) -> np.ndarray:
        """P(the change is right) for every row of ``x`` (M, F)."""
        raw = np.full(len(x), self.base)
        rows = np.arange(len(x))
        for feat, thr, left, right, value, leaf in zip(
            self.feature, self.threshold, self.left, self.right, self.value, self.leaf, strict=True
        ):
            node = np.zeros(len(x), dtype=np.int64)
            while True:
                inner = ~leaf[node]
                if not inner.any():
                    break
                go_left = x[rows, feat[node]] <= thr[node]
                node = np.where(inner, np.where(go_left, left[node], right[node]), node)
            raw += value[node]
        return 1.0 / (1.0 + np.exp(-raw))


@cache
def shipped_model() -> TreeEnsemble:
    """The model shipped with the library (read once per process)."""
    return TreeEnsemble.from_json(MODEL_PATH)


def learned_labels(
    seg: np.ndarray,
    n_seg: int,
    labels: np.ndarray,
    probs: np.ndarray,
    *,
    threshold: float,
    model: TreeEnsemble | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Fused labels: the segment's label where the model's P(right) exceeds ``threshold``.

    Returns
    -------
    labels : ndarray of shape (N,), int64
    candidate : ndarray of shape (N,), int64
        The segment label every point was offered.
    """
    model = model or shipped_model()
    candidate, open_, features = vote_features(seg, n_seg, labels, probs)
    fused = np.asarray(labels, dtype=np.int64).copy()
    if len(open_):
        take = model.probability(features) > threshold
        fused[open_[take]] = candidate[open_[take]]
    return fused, candidate
