"""Ground-detection counts: how a detector's floor mask compares with ground labels.

Filled by the texture stage on labelled frames (`TextureResult.detection`) and reported
by `slamlab.eval.texture.texture_metrics`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(slots=True)
class DetectionCounts:
    """Pixel counts of one detector against ground labels, summed over labelled frames.
    Only valid depth pixels (the ones a detector sees) are counted."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0
    frames: int = 0

    def add(self, predicted: np.ndarray, truth: np.ndarray) -> None:
        """Add one frame: `predicted`, `truth` (M,) bool over the same points."""
        p = np.asarray(predicted, dtype=bool)
        t = np.asarray(truth, dtype=bool)
        tp = int(np.count_nonzero(p & t))
        np_ = int(np.count_nonzero(p))
        nt = int(np.count_nonzero(t))
        self.tp += tp
        self.fp += np_ - tp
        self.fn += nt - tp
        self.tn += int(p.size) - np_ - nt + tp
        self.frames += 1

    @property
    def precision(self) -> float:
        """TP / (TP + FP); NaN if nothing was predicted."""
        d = self.tp + self.fp
        return self.tp / d if d else float("nan")

    @property
    def recall(self) -> float:
        """TP / (TP + FN); NaN if no pixel is labelled floor."""
        d = self.tp + self.fn
        return self.tp / d if d else float("nan")

    def as_dict(self) -> dict:
        p, r = self.precision, self.recall
        f1 = 2 * p * r / (p + r) if (p + r) > 0 else float("nan")
        return {
            "precision": p, "recall": r, "f1": f1, "frames": self.frames,
            "tp": self.tp, "fp": self.fp, "fn": self.fn, "tn": self.tn,
        }  # fmt: skip
