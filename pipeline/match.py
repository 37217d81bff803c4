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
    # BFMatcher.knnMatch's own search, returned as arrays rather than DMatch objects to unpack
    # in Python.
    dist, idx = cv2.batchDistance(query, train, cv2.CV_32S if norm == cv2.NORM_HAMMING else cv2.CV_32F,
                                  normType=norm, K=2)
    keep = dist[:, 0] < ratio * dist[:, 1]
    q, t, d = np.flatnonzero(keep), idx[keep, 0].astype(np.int64), dist[keep, 0].astype(np.float32)
    order = np.lexsort((d, t))  # by train index, closest first
    q, t, d = q[order], t[order], d[order]
    first = np.ones(len(t), dtype=bool)
    first[1:] = t[1:] != t[:-1]
    return Matches(q[first], t[first], d[first], len(query))


def match_library(query: np.ndarray, trains: list[np.ndarray], ratio: float,
                  norm: int = cv2.NORM_L2) -> list[Matches]:
    """`ratio_match` of (N, D) query descriptors against each library sign's (M_i, D) descriptors.

    One search per sign rather than one distance matrix against all signs, split after: on
    640x480 crops against the sample library, cv2.gemm and the per-sign nearest two on its
    result took 0.7-4 ms, the three searches 0.4-0.7 ms; numpy's product is faster but leaves
    OpenBLAS threads spinning after each call, which cost the whole pipeline 15-25 % more CPU.
    """
    return [ratio_match(query, train, ratio, norm) for train in trains]
