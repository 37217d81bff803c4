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
    dist, idx = nearest_two(query, train, norm)
    keep = dist[:, 0] < ratio * dist[:, 1]
    q, t, d = np.flatnonzero(keep), idx[keep, 0].astype(np.int64), dist[keep, 0].astype(np.float32)
    order = np.lexsort((d, t))  # by train index, closest first
    q, t, d = q[order], t[order], d[order]
    first = np.ones(len(t), dtype=bool)
    first[1:] = t[1:] != t[:-1]
    return Matches(q[first], t[first], d[first], len(query))


def nearest_two(query: np.ndarray, train: np.ndarray, norm: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) distances and (N, 2) int indices of the two train descriptors nearest each of the (N, D)
    query descriptors among the (M, D), M >= 2, train ones, nearest first.

    Hamming distances by BFMatcher.knnMatch's own search (cv2.batchDistance). L2 as one matrix
    product, |q - t|² = |q|² + |t|² - 2 q·t: SIFT's descriptors are whole numbers of at most 255 and
    norm about 512, so every sum is a whole number below 2^24, exact in float32 in any order, and the
    distances are batchDistance's to the bit. CPU time per call on the 2-core VM under load: 763
    frame features against a sign's 1500 simulated steep views 4.1 ms (OpenCV's OpenBLAS, whose
    second thread waits spinning after a call; on one thread 0.5 ms for 100 of them) against
    batchDistance's 21.6 ms; on a frame without a sign, every search and the affine fallback's
    together, 28 ms against 40 ms per image, 8 ms on one OpenBLAS thread.
    """
    if norm == cv2.NORM_HAMMING:
        return cv2.batchDistance(query, train, cv2.CV_32S, normType=norm, K=2)
    query, train = query.astype(np.float32, copy=False), train.astype(np.float32, copy=False)
    # |t|² - 2 q·t as one product of [q, 1] and [-2 t, |t|²]; |q|², the same along a row, is added to the
    # two nearest alone (whole numbers: the order and every tie are the same): two passes fewer over the
    # (N, M) matrix, 7-13 % of the call (763 frame features against a sign's 1336-1581 simulated views:
    # 3.3-3.9 ms against 3.7-4.2 on one thread).
    ones = np.ones((len(query), 1), np.float32)
    lifted = np.hstack([-2.0 * train, np.einsum("ij,ij->i", train, train)[:, None]])
    squared = cv2.gemm(np.hstack([query, ones]), lifted, 1.0, None, 0.0, flags=cv2.GEMM_2_T)
    rows = np.arange(len(query))
    first = squared.argmin(axis=1)
    nearest = squared[rows, first]
    squared[rows, first] = np.inf  # a row's argmin once more finds its second nearest (argpartition: 35 times slower)
    second = squared.argmin(axis=1)
    own = np.einsum("ij,ij->i", query, query)[:, None]
    distances = np.sqrt(np.maximum(np.stack([nearest, squared[rows, second]], axis=1) + own, 0.0))
    return distances, np.stack([first, second], axis=1)


def match_library(query: np.ndarray, trains: list[np.ndarray], ratio: float,
                  norm: int = cv2.NORM_L2) -> list[Matches]:
    """`ratio_match` of (N, D) query descriptors against each library sign's (M_i, D) descriptors.

    One product per sign (`nearest_two`): numpy's product, as fast, leaves its own OpenBLAS's
    threads spinning after each call, which cost the whole pipeline 15-25 % more CPU.
    """
    return [ratio_match(query, train, ratio, norm) for train in trains]
