"""The learned vote's model at run time: the gradient-boosted trees of ``vote_model.json``
read from plain JSON and evaluated with numpy (:mod:`jointseg.fusion.trees` does the sums).

Why plain JSON and numpy: no learning library is needed to run the vote; scikit-learn is needed
only to fit it (:mod:`jointseg.fitting.vote_trees`, which exports the trees read here).
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass
from functools import cache, cached_property
from pathlib import Path

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.fusion.offers import (
    DEFAULT_CELL_SIZE,
    FEATURES,
    FEATURES_BEFORE_STRUCTURE,
    POINT_FEATURES,
)
from jointseg.fusion.trees import (
    PLANS_KEPT,
    Rows,
    TreePlan,
    constant_features,
    plan_tree,
    raw_scores,
    split_thresholds,
    varying_cuts,
)

#: The model shipped with the library.
MODEL_PATH = Path(__file__).with_name("vote_model.json")

#: Guards each model's cache of specialised trees (fusions may run in threads).
_PLANS_LOCK = threading.Lock()


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
    cell_size: float = DEFAULT_CELL_SIZE
    n_features: int = len(FEATURES)

    @property
    def weighs_structure(self) -> bool:
        """Whether the model was fitted with the structure reading's offers and features."""
        return self.n_features == len(FEATURES)

    @classmethod
    def from_json(cls, path: Path) -> TreeEnsemble:
        """Read a model written by `jointseg fit vote`; a missing file is a ConfigError naming
        it (an installation without the shipped model must not fuse without it)."""
        if not path.is_file():
            incomplete = ": the jointseg installation is incomplete; reinstall jointseg"
            why = incomplete if path == MODEL_PATH else ""
            raise ConfigError(f"the vote model {path} is missing{why}")
        try:
            body = json.loads(path.read_text())
            trees = body["trees"]
            if body["features"] not in (list(FEATURES), list(FEATURES_BEFORE_STRUCTURE)):
                raise ConfigError(f"{path}: features {body['features']} are not {list(FEATURES)}")
            cell_size = float(body.get("cell_size", DEFAULT_CELL_SIZE))
            if not np.isfinite(cell_size) or cell_size < 0:
                raise ConfigError(f"{path}: cell_size must be a length >= 0 (m), got {cell_size}")
            return cls(
                base=float(body["base"]),
                feature=[np.asarray(t["feature"], np.int64) for t in trees],
                threshold=[np.asarray(t["threshold"], np.float64) for t in trees],
                left=[np.asarray(t["left"], np.int64) for t in trees],
                right=[np.asarray(t["right"], np.int64) for t in trees],
                value=[np.asarray(t["value"], np.float64) for t in trees],
                leaf=[np.asarray(t["leaf"], bool) for t in trees],
                card=dict(body.get("card", {})),
                cell_size=cell_size,
                n_features=len(body["features"]),
            )
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"vote model {path}: {exc}") from exc

    def probability(self, x: np.ndarray, context: np.ndarray | None = None) -> np.ndarray:
        """P(the change is right) for every row of ``x`` (M, F): the sigmoid of
        :meth:`decision`."""
        return 1.0 / (1.0 + np.exp(-self.decision(x, context)))

    def decision(self, x: np.ndarray, context: np.ndarray | None = None) -> np.ndarray:
        """The ensemble's raw score (log-odds) for every row of ``x`` (M, F): its base plus
        each tree's leaf value, added in the trees' order (:mod:`jointseg.fusion.trees`).

        ``context`` (M,), optional: rows with equal context have equal features except
        :data:`POINT_FEATURES` (:attr:`Offers.context`); their other splits are then taken once
        per context. The result is the same to the bit with it or without."""
        x = np.asarray(x, dtype=np.float64)[:, : self.n_features]
        if len(x) == 0:
            return np.zeros(0)
        varying = frozenset(POINT_FEATURES if context is not None else ())
        plans, cuts = self._plans(constant_features(x, self._used_features), varying)
        rows = Rows.each(len(x)) if context is None else Rows.grouped(x, context, cuts)
        raw = raw_scores(self, x, plans, rows)
        return raw if rows.inverse is None else raw[rows.inverse]

    @cached_property
    def _thresholds(self) -> list[np.ndarray]:
        """Per feature, the sorted distinct thresholds of its splits."""
        return split_thresholds(self, self.n_features)

    @cached_property
    def _used_features(self) -> list[int]:
        """The features some split tests."""
        return [f for f, cuts in enumerate(self._thresholds) if len(cuts)]

    @cached_property
    def _plan_cache(self) -> dict[tuple, tuple[list[TreePlan], dict[int, np.ndarray]]]:
        return {}

    def _plans(
        self, fixed: dict[int, float], varying: frozenset[int]
    ) -> tuple[list[TreePlan], dict[int, np.ndarray]]:
        """Every tree specialised to the constant features ``fixed``, and the thresholds of
        the ``varying`` features' splits left (kept for the next call with the same constants:
        the tiles of a scan share them)."""
        key = (tuple(sorted(fixed.items())), varying)
        with _PLANS_LOCK:
            cache = self._plan_cache
            if key not in cache:
                if len(cache) >= PLANS_KEPT:
                    cache.pop(next(iter(cache)))
                plans = [plan_tree(self, t, fixed, varying) for t in range(len(self.feature))]
                cache[key] = plans, varying_cuts(plans)
            return cache[key]


@cache
def shipped_model() -> TreeEnsemble:
    """The model shipped with the library (read once per process)."""
    return TreeEnsemble.from_json(MODEL_PATH)
