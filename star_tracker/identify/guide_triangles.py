# SPDX-License-Identifier: Apache-2.0
"""
Which catalog triangles exist.

Guide stars thinned over the sky, and every triangle of guide stars whose three sides are at
most a limit, as rows of star indices sorted ascending (so a triangle's handedness is the
sign of det[v_a, v_b, v_c]).

For wide fields the full catalog gives tens of millions of triangles, so guide stars are
thinned to the brightest `per_cell` of each cell of an equal-angle cube-sphere grid
(uniform sky coverage, brightest stars kept).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .database import StarDatabase


def sky_cells(vectors: np.ndarray, cells_per_face: int) -> np.ndarray:
    """
    Return the cell id of each unit vector on an equal-angle cube-sphere grid.

    cells_per_face^2 cells on each of the six faces (cell areas within a factor ~1.4).
    """
    vectors = np.asarray(vectors, dtype=float)
    axis = np.argmax(np.abs(vectors), axis=1)
    rows = np.arange(vectors.shape[0])
    major = vectors[rows, axis]
    face = 2 * axis + (major > 0)
    other1 = np.array([1, 0, 0])[axis]
    other2 = np.array([2, 2, 1])[axis]
    n = cells_per_face
    cell = []
    for other in (other1, other2):
        angle = np.arctan(vectors[rows, other] / np.abs(major))  # in [-pi/4, pi/4]
        cell.append(np.clip(np.floor((angle + np.pi / 4) / (np.pi / 2) * n), 0, n - 1).astype(np.int64))
    return (face * n + cell[0]) * n + cell[1]


def brightest_per_cell(vectors: np.ndarray, magnitude: np.ndarray, cells_per_face: int, per_cell: int) -> np.ndarray:
    """Return indices (ascending) of the `per_cell` brightest stars of each sky cell."""
    cell = sky_cells(vectors, cells_per_face)
    order = np.lexsort((np.arange(cell.size), magnitude, cell))
    sorted_cell = cell[order]
    first = np.searchsorted(sorted_cell, sorted_cell, side="left")
    rank = np.arange(cell.size) - first
    return np.sort(order[rank < per_cell])


def pair_graph(database: StarDatabase, stars: np.ndarray, max_side: float) -> tuple[np.ndarray, np.ndarray]:
    """
    CSR of 'later' neighbours among `stars` (positions into `stars`): j > i and the pair's angle <= max_side.

    Columns ascending.
    """
    pair_a, pair_b = database.pairs_in_range(0.0, max_side)
    position = np.full(database.star_count, -1, np.int64)
    position[stars] = np.arange(stars.size)
    a, b = position[pair_a], position[pair_b]
    keep = (a >= 0) & (b >= 0)
    a, b = a[keep], b[keep]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.lexsort((hi, lo))
    lo, hi = lo[order], hi[order]
    indptr = np.zeros(stars.size + 1, np.int64)
    np.cumsum(np.bincount(lo, minlength=stars.size), out=indptr[1:])
    return indptr, hi.astype(np.int32)


@njit(cache=True)
def graph_triangles_kernel(indptr, indices, out):
    """
    Count (out of size 0) or list the triangles i < j < k of the graph.

    Every j, k > i adjacent to i with k adjacent to j.
    """
    n = indptr.size - 1
    mark = np.zeros(n, np.bool_)
    count = 0
    fill = out.shape[0] > 0
    for i in range(n):
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            for q in range(indptr[j], indptr[j + 1]):
                mark[indices[q]] = True
            for p2 in range(p + 1, indptr[i + 1]):
                k = indices[p2]
                if mark[k]:
                    if fill:
                        out[count, 0], out[count, 1], out[count, 2] = i, j, k
                    count += 1
            for q in range(indptr[j], indptr[j + 1]):
                mark[indices[q]] = False
    return count


def graph_triangles(indptr: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """(T, 3) the triangles i < j < k of the graph `pair_graph` returns (positions)."""
    count = graph_triangles_kernel(indptr, indices, np.zeros((0, 3), np.int64))
    local = np.empty((count, 3), np.int64)
    graph_triangles_kernel(indptr, indices, local)
    return local


def count_triangles(database: StarDatabase, stars: np.ndarray, max_side: float) -> int:
    indptr, indices = pair_graph(database, stars, max_side)
    return int(graph_triangles_kernel(indptr, indices, np.zeros((0, 3), np.int64)))
