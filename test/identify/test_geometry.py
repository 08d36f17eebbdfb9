# SPDX-License-Identifier: Apache-2.0
"""The identification geometry (identify/geometry.py) against independent computations."""
import itertools

import numpy as np
from numba import njit

from star_tracker.identify.geometry import (angle_between, chord2_rows, chord_angle, pyramid_order, pyramid_triangles,
                                            triple_product, triple_product_rows, triple_products)


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@njit
def _compiled(u, v, w, rows):
    """Return the scalar forms as kernels call them (inlined into a compiled caller)."""
    return (angle_between(u, v), triple_product(u, v, w), chord2_rows(rows, 0, 1),
            triple_product_rows(rows, 0, 1, 2))


def test_chord_angle_is_exact_where_arccos_loses_digits():
    # Two directions a known angle apart, from 1e-9 rad (arccos of the dot product returns
    # ~1e-8 or 0 there) to nearly pi.
    for angle in (1e-9, 1e-6, 1e-3, 0.3, 1.5, 3.0):
        u = np.array([1.0, 0.0, 0.0])
        v = np.array([np.cos(angle), np.sin(angle), 0.0])
        assert abs(float(chord_angle(u, v)) - angle) <= 1e-15 + 1e-14 * angle
        assert abs(_compiled(u, v, v, np.stack([u, v, v]))[0] - angle) <= 1e-15 + 1e-14 * angle
    assert abs(float(np.arccos(np.clip(u @ np.array([np.cos(1e-9), np.sin(1e-9), 0.0]), -1, 1))) - 1e-9) > 1e-10


def test_scalar_and_vectorised_forms_agree_with_numpy():
    rng = np.random.default_rng(3)
    u, v, w = (unit(rng.normal(size=(200, 3))) for _ in range(3))
    expected_angle = np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.einsum("ni,ni->n", u, v))
    np.testing.assert_allclose(chord_angle(u, v), expected_angle, rtol=1e-12, atol=1e-15)
    determinants = np.linalg.det(np.stack([u, v, w], axis=1))
    np.testing.assert_allclose(triple_products(u, v, w), determinants, rtol=1e-10, atol=1e-14)
    for t in range(20):
        rows = np.stack([u[t], v[t], w[t]])
        angle, det, chord2, det_rows = _compiled(u[t], v[t], w[t], rows)
        assert abs(angle - expected_angle[t]) <= 1e-14
        assert abs(det - determinants[t]) < 1e-14 and det_rows == det
        assert abs(chord2 - np.sum((u[t] - v[t]) ** 2)) < 1e-15
    # Right-handed (counter-clockwise seen from outside) triples are positive.
    assert triple_product(np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0])) == 1.0


def test_pyramid_order_visits_every_triple_once_with_slowly_growing_gaps():
    for n in (3, 4, 7, 12):
        triples = pyramid_triangles(n)
        assert triples.shape == (len(list(itertools.combinations(range(n), 3))), 3)
        assert {tuple(t) for t in triples.tolist()} == set(itertools.combinations(range(n), 3))
        assert list(pyramid_order(n)) == [tuple(t) for t in triples.tolist()]
        gaps = np.column_stack([triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 1]])
        # Mortari's order: the first gap grows slowest, then the second, then the start index.
        keys = list(zip(gaps[:, 0], gaps[:, 1], triples[:, 0]))
        assert keys == sorted(keys)
    assert pyramid_triangles(5)[:4].tolist() == [[0, 1, 2], [1, 2, 3], [2, 3, 4], [0, 1, 3]]
    assert pyramid_triangles(2).shape == (0, 3)
