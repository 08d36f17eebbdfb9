# SPDX-License-Identifier: Apache-2.0
"""
Cole & Crassidis' spherical triangle method with pivoting (seed 000 sec. III; Cole's thesis 003, sec. 2.4-2.6 and 5.3).

Every triple of pattern spots whose sides fit the catalog forms a spherical triangle with an
area (eq. 15) and a polar moment (eq. 25), each with a 1-sigma (eqs. 17-24; see
`triangle_invariants`, `polar_moment`). Catalog triangles within beta sigma of the area are
found with the k-vector; those whose polar moment is also within beta sigma are the
"finalists". Beyond the paper, which only names the stars, each finalist's vertices are
assigned to the spots by the sides (all three within the angle tolerance) and its handedness
must be the spots' (mirror test).

Pivoting (thesis 5.3.3-5.3.5): the first triangle is the one with the largest area (the
fewest solutions); each pivot is the largest unused triangle sharing two spots with the
current one. Finalists are carried as joint assignments spot -> star of the whole chain, so a
pivot keeps only the assignments whose shared spots' stars also solve the pivot triangle
(the thesis keeps solutions sharing two stars). When at most `max_final` assignments remain
they are the hypotheses; at most `pivot_limit` pivots per chain (paper: 3).

Beyond the paper, which stops with "inconclusive": triangles without a finalist (a false star,
a star missing from the catalog) are left out of the pivot order, and when a chain fails (or
its solution fails verification) a new one starts from the next largest triangle, until the
time budget is spent.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .base import IdentifyConfig, StarIdentifier
from .spot_geometry import SpotGeometry
from .database import StarDatabase
from .triangle_database import TriangleConfig, load_or_build_triangles
from .triangle_features import measured_features, spherical_area, triangle_sides
from .triangle_matching import match_triangles, warm_up
from .deadline import Deadline


@dataclass(frozen=True)
class SphericalTriangleSettings:
    """
    pivot_limit: pivots per chain (Cole: 3).

    max_final: a chain yields its assignments once at most this many remain (Cole: 1, a unique
    solution); max_leftover: a chain that ends without one (pivot limit, or no triangle to
    pivot to) still yields its assignments if at most this many remain, for verification to
    decide (Cole: 0, "inconclusive"); max_assignments: a triangle with more vertex assignments
    is rejected as ambiguous (Cole rejects triangles with > 10,000 solutions); max_joint: a
    chain whose joint assignments exceed this is abandoned; side_check: assign a finalist's
    vertices by the sides and drop it if none fits (False: as in the paper, only area, moment
    and handedness, so each finalist enters with its three handedness-preserving assignments
    and pivoting decides).
    """

    pivot_limit: int = 3
    max_final: int = 1
    max_leftover: int = 4
    max_assignments: int = 10000
    max_joint: int = 20000
    side_check: bool = True

    def __post_init__(self) -> None:
        if not (0 <= self.pivot_limit <= 100):
            raise ValueError(f"pivot_limit={self.pivot_limit} must be in [0, 100]")
        if not (1 <= self.max_final <= 1000):
            raise ValueError(f"max_final={self.max_final} must be in [1, 1000]")
        if not (0 <= self.max_leftover <= 1000):
            raise ValueError(f"max_leftover={self.max_leftover} must be in [0, 1000]")
        if not (1 <= self.max_assignments <= 1_000_000):
            raise ValueError(f"max_assignments={self.max_assignments} must be in [1, 1e6]")
        if not (1 <= self.max_joint <= 10_000_000):
            raise ValueError(f"max_joint={self.max_joint} must be in [1, 1e7]")


def spot_triples(count: int) -> np.ndarray:
    """(T, 3) all index triples i < j < k < count."""
    if count < 3:
        return np.zeros((0, 3), np.int64)
    return np.array(list(itertools.combinations(range(count), 3)), np.int64)


def fitting_triples(rays: np.ndarray, triples: np.ndarray, max_side: float, slack: float) -> np.ndarray:
    """Return the triples whose three sides are all <= max_side + slack [rad]."""
    cos_limit = np.cos(min(max_side + slack, np.pi))
    dots = rays @ rays.T
    ok = ((dots[triples[:, 0], triples[:, 1]] >= cos_limit) & (dots[triples[:, 1], triples[:, 2]] >= cos_limit)
          & (dots[triples[:, 2], triples[:, 0]] >= cos_limit))
    return triples[ok]


def join_assignments(spots: list[int], table: np.ndarray, triangle: np.ndarray, candidates: np.ndarray,
                     star_count: int) -> tuple[list[int], np.ndarray]:
    """
    Join the chain's joint assignments `table` (M, len(spots)) with a triangle's candidates.

    The candidates (C, 3) are stars of its vertex spots `triangle`, which shares >= 2 spots with
    the chain: rows must agree on the shared spots' stars and stay one-to-one.
    """
    shared = [m for m in range(3) if triangle[m] in spots]
    p, q = shared[0], shared[1]
    col_p, col_q = spots.index(triangle[p]), spots.index(triangle[q])
    key_cand = candidates[:, p].astype(np.int64) * star_count + candidates[:, q]
    key_rows = table[:, col_p].astype(np.int64) * star_count + table[:, col_q]
    order = np.argsort(key_cand, kind="stable")
    key_sorted = key_cand[order]
    lo = np.searchsorted(key_sorted, key_rows, "left")
    hi = np.searchsorted(key_sorted, key_rows, "right")
    counts = hi - lo
    rows = np.repeat(np.arange(table.shape[0]), counts)
    picks = order[np.repeat(lo, counts) + (np.arange(rows.size) - np.repeat(np.cumsum(counts) - counts, counts))]
    joined, cand = table[rows], candidates[picks]
    r = [m for m in range(3) if m not in (p, q)][0]
    if len(shared) == 3:  # every vertex already in the chain: the third must agree too
        keep = joined[:, spots.index(triangle[r])] == cand[:, r]
        return spots, joined[keep]
    new_star = cand[:, r]
    distinct = np.all(joined != new_star[:, None], axis=1)
    return spots + [int(triangle[r])], np.column_stack([joined[distinct], new_star[distinct]])


class SphericalTriangleIdentifier(StarIdentifier):
    """Spherical triangle matching with pivoting (Cole & Crassidis)."""

    name = "spherical_triangle"

    def __init__(self, database: StarDatabase, config: IdentifyConfig,
                 triangle_config: TriangleConfig | None = None,
                 settings: SphericalTriangleSettings | None = None):
        super().__init__(database, config)
        self.triangles = load_or_build_triangles(database, triangle_config)
        self.settings = settings or SphericalTriangleSettings()
        warm_up(self.triangles, database)

    def hypotheses(self, geometry: SpotGeometry, deadline: Deadline) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        tconf = self.triangles.config
        rays, sigma = geometry.rays, geometry.sigma
        worst = np.max(sigma[: geometry.pattern_count])
        triples = fitting_triples(rays, spot_triples(geometry.pattern_count), tconf.max_side_rad,
                                  float(self.angle_tolerance(worst, worst)))
        self.stats.update(triangles=int(triples.shape[0]), matched=0, area_candidates=0, finalists=0,
                          chains=0, pivots=0)
        if triples.shape[0] == 0:
            return
        sides = triangle_sides(rays[triples[:, 0]], rays[triples[:, 1]], rays[triples[:, 2]])
        memo: dict[int, np.ndarray] = {}

        def candidates(t: int) -> np.ndarray:
            """Vertex assignments (C, 3) of spot triangle t, measured and looked up on first use."""
            if t not in memo:
                features = measured_features(rays, sigma, triples[t:t + 1], spherical=True, depth=tconf.moment_depth,
                                             beta=self.config.sigma_multiplier,
                                             floor=self.config.angle_tolerance_floor_rad)
                found = match_triangles(self.triangles, self.database, features, spherical=True,
                                        cap=self.settings.max_assignments, check_sides=self.settings.side_check)
                memo[t] = found.stars
                self.stats["matched"] += 1
                self.stats["area_candidates"] += int(found.area_candidates[0])
                self.stats["finalists"] += int(max(found.finalists[0], 0))
            return memo[t]

        # Pivot order by area, largest first (thesis 5.3.3).
        order = [int(t) for t in np.argsort(-spherical_area(sides), kind="stable")]
        spot_sets = [set(map(int, tri)) for tri in triples]
        yielded: set[tuple] = set()
        for start in order:
            if deadline.passed():
                return
            if candidates(start).shape[0] == 0:
                continue  # no finalist: a false star or one missing from the catalog
            self.stats["chains"] += 1
            spots, table = [int(s) for s in triples[start]], candidates(start)
            used, current, pivots, excluded = {start}, start, 0, set()
            while 0 < table.shape[0] <= self.settings.max_joint:
                if table.shape[0] <= self.settings.max_final:
                    break
                chosen = None
                if pivots < self.settings.pivot_limit and not deadline.passed():
                    chosen = self._next_pivot(order, used, spot_sets, current, set(spots), excluded, candidates,
                                              deadline)
                if chosen is None:  # inconclusive
                    if table.shape[0] > self.settings.max_leftover:
                        table = table[:0]
                    break
                used.add(chosen)
                pivots += 1
                self.stats["pivots"] += 1
                joined_spots, joined = join_assignments(spots, table, triples[chosen], candidates(chosen),
                                                        self.database.star_count)
                if joined.shape[0] == 0:
                    # No assignment survives: distrust the pivot's new spot (a false star?)
                    # rather than the whole chain.
                    excluded |= spot_sets[chosen] - set(spots)
                    continue
                spots, table, current = joined_spots, joined, chosen
            if table.shape[0] > self.settings.max_joint:
                continue
            self.stats["chain_pivots"] = pivots
            for row in table:
                key = tuple(sorted(zip(spots, row.tolist())))
                if key not in yielded:
                    yielded.add(key)
                    yield np.array(spots), row.astype(np.int64)

    @staticmethod
    def _next_pivot(order: list[int], used: set[int], spot_sets: list[set], current: int, chain_spots: set[int],
                    excluded: set[int], candidates, deadline: Deadline) -> int | None:
        """
        Return the largest unused triangle with finalists sharing two spots with the current one.

        Thesis 5.3.3; else one sharing any two of the chain's spots; none with excluded spots.
        """
        for pool in (spot_sets[current], chain_spots):
            for t in order:  # descending area
                if deadline.passed():
                    return None
                if (t not in used and len(spot_sets[t] & pool) >= 2 and not spot_sets[t] & excluded
                        and candidates(t).shape[0] > 0):
                    return t
        return None
