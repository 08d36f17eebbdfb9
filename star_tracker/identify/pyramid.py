# SPDX-License-Identifier: Apache-2.0
"""
Triangle matching with k-vector pair search in Mortari's pyramid order.

For spot triangles (i, j, k) taken in the pyramid enumeration order (which moves away from
a false spot as fast as possible), each side's angle is looked up in the k-vector; catalog
triangles whose three sides all match and whose handedness (sign of the triple product)
agrees with the spots' are the hypotheses. The 4th-star confirmation of the Pyramid method
is done by the shared verification, which checks every other spot at once.
"""
from __future__ import annotations

import numpy as np

from .base import StarIdentifier
from .spot_geometry import SpotGeometry
from .geometry import chord_angle, pyramid_order, triple_products
from .deadline import Deadline


class PyramidIdentifier(StarIdentifier):
    name = "pyramid"

    def hypotheses(self, geometry: SpotGeometry, deadline: Deadline):
        rays, sigma = geometry.rays, geometry.sigma
        n_stars = self.database.star_count
        vectors = self.database.vectors
        for i, j, k in pyramid_order(geometry.pattern_count):
            edges = []
            for a, b in ((i, j), (i, k), (j, k)):
                angle = float(chord_angle(rays[a], rays[b]))
                tol = float(self.angle_tolerance(sigma[a], sigma[b]))
                edges.append(self.database.pairs_in_range(angle - tol, angle + tol))
            (ij_a, ij_b), (ik_a, ik_b), (jk_a, jk_b) = edges
            if ij_a.size == 0 or ik_a.size == 0 or jk_a.size == 0:
                continue
            # Directed edges: star for spot i -> star for spot j (both orientations of each pair).
            from_i_j = np.concatenate([ij_a, ij_b])
            to_j = np.concatenate([ij_b, ij_a])
            from_i_k = np.concatenate([ik_a, ik_b])
            to_k = np.concatenate([ik_b, ik_a])
            order = np.argsort(from_i_k, kind="stable")
            from_i_k, to_k = from_i_k[order], to_k[order]
            lo = np.searchsorted(from_i_k, from_i_j, "left")
            hi = np.searchsorted(from_i_k, from_i_j, "right")
            counts = hi - lo
            total = int(counts.sum())
            if total == 0:
                continue
            edge_ij = np.repeat(np.arange(from_i_j.size), counts)
            starts = np.repeat(lo - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
            edge_ik = starts + np.arange(total)
            star_i, star_j, star_k = from_i_j[edge_ij], to_j[edge_ij], to_k[edge_ik]
            distinct = star_j != star_k
            star_i, star_j, star_k = star_i[distinct], star_j[distinct], star_k[distinct]
            # Third side: is (star_j, star_k) a pair in the j-k window?
            codes = np.sort(np.minimum(jk_a, jk_b).astype(np.int64) * n_stars + np.maximum(jk_a, jk_b))
            query = np.minimum(star_j, star_k).astype(np.int64) * n_stars + np.maximum(star_j, star_k)
            pos = np.clip(np.searchsorted(codes, query), 0, codes.size - 1)
            hit = codes[pos] == query
            star_i, star_j, star_k = star_i[hit], star_j[hit], star_k[hit]
            if star_i.size == 0:
                continue
            # Mirror test: a reflected sky has the opposite handedness.
            spot_sign = np.sign(triple_products(rays[[i]], rays[[j]], rays[[k]]))
            star_sign = np.sign(triple_products(vectors[star_i], vectors[star_j], vectors[star_k]))
            same = star_sign == spot_sign
            star_i, star_j, star_k = star_i[same], star_j[same], star_k[same]
            if star_i.size > self.config.max_candidates_per_pattern:
                continue  # ambiguous pattern: try another
            for a, b, c in zip(star_i, star_j, star_k):
                yield np.array([i, j, k]), np.array([a, b, c])
