"""Scores of a world model's predictions on a test set, overall and per outcome stratum.

For every object in every test episode the model predicts where it ends up (x, y, z, yaw). From that:

- ``f1``: F1 of "moves" (the predicted displacement, as the truth's, over `MOVED`) over object-episodes;
- ``err_cm``: the median error of the predicted final (x, y) over the object-episodes that truly moved, beside
  ``nothing_cm``, the same for "nothing moves" (the true displacement), and ``mean_cm``, for the training set's mean
  displacement of that object (over its moved episodes); ``ratio`` is ``err_cm / nothing_cm`` and ``skill`` is
  ``1 - ratio`` (0: no better than "nothing moves"; 1: exact), ``mean_skill`` the same against the mean;
- ``yaw_deg``: the median error of the final yaw of the moved objects that have one (boxes, modulo their symmetry);
- ``false_moves``: the share of object-episodes that did not move but are predicted to;
- ``along``: the median over the moved objects of the predicted (dx, dy) along the true one, in its units
  (`in_true_units`: 1 as far as it went, 0 not at all, below 0 the wrong way).

Each is reported on the whole test set and on each stratum (`STRATA`); ``macro`` averages the strata that have
episodes (F1 and the error ratio over those with moved objects); ``shapes`` holds the same for each shape
(`babblegen.shapes.SHAPES`) of the test set's objects, counting those objects alone.
"""

from __future__ import annotations

import numpy as np

from babblegen.shapes import SHAPES
from babblegen.worldmodel.episodes import MOVED, STRATA, EpisodeSet, outcomes
from babblegen.worldmodel.poses import object_state, wrap


def mean_displacement(train: EpisodeSet) -> np.ndarray:
    """(K, 2) each object's mean (dx, dy) over the training episodes in which it moved (0 where it never did)."""
    moved, _ = outcomes(train)
    d = train.final[..., :2] - train.first[..., :2]
    counts = moved.sum(axis=0)
    return np.where(counts[:, None] > 0, (d * moved[..., None]).sum(axis=0) / np.maximum(counts, 1)[:, None], 0.0)


def in_true_units(predicted: np.ndarray, true: np.ndarray) -> np.ndarray:
    """(..., 2) predicted (dx, dy) displacements (..., 2) in units of the true ones: along the true displacement
    (1: as far as it went, 0: not at all) and across it (positive to its left)."""
    length2 = np.maximum((true**2).sum(axis=-1), 1e-12)
    along = (predicted * true).sum(axis=-1) / length2
    across = (true[..., 0] * predicted[..., 1] - true[..., 1] * predicted[..., 0]) / length2
    return np.stack([along, across], axis=-1)


def ends_in_true_units(pred: np.ndarray, first: np.ndarray, final: np.ndarray) -> np.ndarray:
    """(E, K, 2) where predicted final states ``pred`` (E, K, >=2) end each object, from ``first`` (its start), in
    units of its true move to ``final`` (`in_true_units`)."""
    return in_true_units(pred[..., :2] - first[..., :2], final[..., :2] - first[..., :2])


def _median(values: np.ndarray) -> float:
    return float(np.median(values)) if values.size else float("nan")


def _scores(pred: np.ndarray, first: np.ndarray, final: np.ndarray, moved: np.ndarray, mean: np.ndarray, sym,
            pick: np.ndarray | None = None):  # fmt: skip
    """The scores of one group of episodes: ``pred``, ``first``, ``final`` (E, K, 4) states, ``sym`` (E, K) the
    objects' yaw symmetries, ``pick`` (E, K) the objects counted (None: all)."""
    pick = np.ones(moved.shape, dtype=bool) if pick is None else pick
    moved = moved & pick
    pred_moved = (np.linalg.norm(pred[..., :3] - first[..., :3], axis=-1) > MOVED) & pick
    tp = float((pred_moved & moved).sum())
    denominator = float(pred_moved.sum() + moved.sum())
    err = np.linalg.norm(pred[..., :2] - final[..., :2], axis=-1)[moved] * 100
    nothing = np.linalg.norm(first[..., :2] - final[..., :2], axis=-1)[moved] * 100
    guess = first[..., :2] + mean[None]
    mean_err = np.linalg.norm(guess - final[..., :2], axis=-1)[moved] * 100
    has_yaw = moved & (sym > 0)
    period = np.where(sym > 0, sym, 2 * np.pi)
    yaw_err = np.abs(wrap(pred[..., 3] - final[..., 3], period))[has_yaw]
    still = ~moved & pick
    out = {
        "episodes": int(pick.any(axis=1).sum()),
        "moved": int(moved.sum()),
        "f1": 2 * tp / denominator if moved.any() else float("nan"),
        "err_cm": _median(err),
        "nothing_cm": _median(nothing),
        "mean_cm": _median(mean_err),
        "yaw_deg": float(np.degrees(_median(yaw_err))),
        "false_moves": float(pred_moved[still].mean()) if still.any() else float("nan"),
        "along": _median(ends_in_true_units(pred, first, final)[moved][:, 0]),
    }
    out["ratio"] = out["err_cm"] / out["nothing_cm"] if moved.any() else float("nan")
    out["skill"] = 1 - out["ratio"]
    out["mean_skill"] = 1 - out["err_cm"] / out["mean_cm"] if moved.any() else float("nan")
    return out


def score(pred: np.ndarray, test: EpisodeSet, mean: np.ndarray) -> dict:
    """The scores of predicted final states ``pred`` (E, K, 4) on ``test``: ``all``, each stratum, ``macro``."""
    first, final = object_state(test.first), object_state(test.final)
    moved, stratum = outcomes(test)
    sym = test.yaw_symmetry  # (E, K): each episode's own objects
    out = {"all": _scores(pred, first, final, moved, mean, sym)}
    for i, name in enumerate(STRATA):
        pick = stratum == i
        if pick.any():
            out[name] = _scores(pred[pick], first[pick], final[pick], moved[pick], mean, sym[pick])
    present = [out[s] for s in STRATA if s in out]
    with_moves = [s for s in present if s["moved"]]
    out["macro"] = {
        "f1": float(np.mean([s["f1"] for s in with_moves])) if with_moves else float("nan"),
        "ratio": float(np.mean([s["ratio"] for s in with_moves])) if with_moves else float("nan"),
        "false_moves": float(np.nanmean([s["false_moves"] for s in present])) if present else float("nan"),
    }
    out["macro"]["skill"] = 1 - out["macro"]["ratio"]
    shape = test.shapes
    out["shapes"] = {s: _scores(pred, first, final, moved, mean, sym, shape == s) for s in SHAPES if (shape == s).any()}
    return out
