"""Stage 3: descriptor matching with Lowe's distance-ratio test and one-to-one filtering."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np


@dataclass(frozen=True, eq=False)
class Matches:
    """Tentative correspondences between a query image and one library sign.

    query_idx, train_idx: (M,) int indices into the query's and the sign's features;
    distance: (M,) descriptor distances; n_knn: query features that had two neighbours.
    """

    query_idx: np.ndarray = field(repr=False)
    train_idx: np.ndarray = field(repr=False)
    distance: np.ndarray = field(repr=False)
    n_knn: int

    def __len__(self) -> int:
        return len(self.query_idx)


def empty_matches() -> Matches:
    z = np.zeros(0, dtype=np.int64)
    return Matches(z, z, np.zeros(0, np.float32), 0)


def ratio_match(query: np.ndarray, train: np.ndarray, ratio: float, norm: int = cv2.NORM_L2) -> Matches:
    """Match (N, D) query descriptors to (M, D) train descriptors.

    Keeps a match when its distance is below `ratio` times the second-nearest (VLFeat's default
    threshold 1.5 is ratio 1/1.5), then keeps only the closest of several queries that matched
    the same train descriptor, since many-to-one matches cannot all be right.
    """
    if len(query) < 1 or len(train) < 2:
        return empty_matches()
    knn = cv2.BFMatcher(norm).knnMatch(query, train, k=2)
    pairs = np.array([(m[0].queryIdx, m[0].trainIdx, m[0].distance, m[1].distance) for m in knn if len(m) == 2],
                     dtype=np.float64).reshape(-1, 4)
    keep = pairs[:, 2] < ratio * pairs[:, 3]
    q, t, d = pairs[keep, 0].astype(np.int64), pairs[keep, 1].astype(np.int64), pairs[keep, 2]
    order = np.lexsort((d, t))  # by train index, closest first
    q, t, d = q[order], t[order], d[order]
    first = np.ones(len(t), dtype=bool)
    first[1:] = t[1:] != t[:-1]
    return Matches(q[first], t[first], d[first].astype(np.float32), len(pairs))
