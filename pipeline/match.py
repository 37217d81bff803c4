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


def squared_distances(query: np.ndarray, train: np.ndarray, norm: int = cv2.NORM_L2) -> np.ndarray:
    """(N, M) float32 squared L2 distances between (N, D) query and (M, D) train descriptors.

    For `cv2.NORM_HAMMING` (uint8 binary descriptors) the Hamming distances, which are the
    squared L2 distances of the unpacked 0/1 bit vectors. One matrix product, by cv2.gemm:
    numpy's would go to OpenBLAS, whose threads spin after each call and doubled the
    pipeline's CPU time on a 2-core machine.
    """
    if norm == cv2.NORM_HAMMING:
        query, train = np.unpackbits(query, axis=1), np.unpackbits(train, axis=1)
    q, t = query.astype(np.float32), train.astype(np.float32)
    if not len(q) or not len(t):
        return np.zeros((len(q), len(t)), np.float32)
    d2 = cv2.gemm(q, t, -2.0, None, 0.0, flags=cv2.GEMM_2_T)
    d2 += np.einsum("ij,ij->i", q, q)[:, None]
    d2 += np.einsum("ij,ij->i", t, t)[None, :]
    # |q|^2 + |t|^2 - 2 q.t cancels to slightly below zero for near-identical descriptors.
    return np.maximum(d2, 0, out=d2)


def ratio_test(d2: np.ndarray, ratio: float, norm: int = cv2.NORM_L2) -> Matches:
    """Matches from (N, M) `squared_distances` between query and one sign's descriptors.

    Keeps a match when its distance is below `ratio` times the second-nearest (VLFeat's default
    threshold 1.5 is ratio 1/1.5), then keeps only the closest of several queries that matched
    the same train descriptor, since many-to-one matches cannot all be right.
    """
    n, m = d2.shape
    if n < 1 or m < 2:
        return empty_matches()
    nearest = np.argmin(d2, axis=1)
    two = np.partition(d2, 1, axis=1)[:, :2]
    dist = np.sqrt(two) if norm == cv2.NORM_L2 else two
    keep = dist[:, 0] < ratio * dist[:, 1]
    q, t, d = np.flatnonzero(keep), nearest[keep], dist[keep, 0]
    order = np.lexsort((d, t))  # by train index, closest first
    q, t, d = q[order], t[order], d[order]
    first = np.ones(len(t), dtype=bool)
    first[1:] = t[1:] != t[:-1]
    return Matches(q[first], t[first], d[first], n)


def match_library(query: np.ndarray, trains: list[np.ndarray], ratio: float,
                  norm: int = cv2.NORM_L2) -> list[Matches]:
    """`ratio_test` of (N, D) query descriptors against each library sign's (M_i, D) descriptors,
    from one distance computation over all signs, split per sign after."""
    d2 = squared_distances(query, np.concatenate(trains), norm)
    ends = np.cumsum([len(t) for t in trains])
    return [ratio_test(d2[:, end - len(t):end], ratio, norm) for t, end in zip(trains, ends)]

