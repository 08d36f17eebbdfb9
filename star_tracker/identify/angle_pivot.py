# SPDX-License-Identifier: Apache-2.0
"""
Cole & Crassidis' angle method with pivoting (seed 000 sec. II; Cole's thesis 003, sec. 2.2-2.3, 5.2).

Every pair of spots defines an inter-star angle theta = acos(b_i . b_j) (eq. 1). Its standard
deviation follows from the attitude-independent dot product (eqs. 7-12):
    sigma_p^2 = sigma_i^2 + sigma_j^2 + 3 sigma_i^2 sigma_j^2        (eq. 12)
which is sqrt(2) sigma for equal spot errors (eq. 14; thesis eq. 2.15). The catalog pairs within
theta +- beta sigma_p (beta = IdentifyConfig.sigma_multiplier, plus the configured floor for model
errors) are found with the k-vector.

Pivoting (sec. II.C; thesis 5.2.3-5.2.4): the first angle is the one with the fewest catalog
solutions; each next ("pivot") angle shares one spot with the previous one and is again the one
with the fewest solutions (ties: the larger angle, the thesis' proxy for fewest solutions). The
"finalists" are carried along as partial assignments spot -> star of the whole chain, so a pivot
keeps only those whose shared spot's star also solves the pivot angle (the intersection of the
candidate star sets); when a single finalist covering at least three spots remains, the chain
is solved. At most `pivot_limit` pivots per chain (paper: 9).

Beyond the paper, which reports "inconclusive" whenever this chain fails (the shared
verification arbitrates every hypothesis, so trying more is safe):
  * a pivot that would leave no finalist is skipped and its new spot kept out of the chain (a
    false star or an out-of-tolerance measurement; the paper's main failure with a false star);
  * a solved chain is reduced to its mutually consistent core (every pairwise angle checked, not
    only the chain's) and tested for handedness (sign of the triple product of spots and stars,
    van Bezooijen's mirror test), since angles alone cannot tell a mirrored sky;
  * when a chain ends without a unique finalist, or its solution is rejected, a new chain starts
    from the next angle in the order; then chains that leave out one suspect spot (then two)
    follow, because a false spot kills the true finalist of every chain pivoting through it.
AnglePivotConfig(order_by="angle", max_left_out=0, restart=False, skip_empty_pivots=False) is the
paper's method alone.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .base import StarIdentifier
from .spot_geometry import SpotGeometry
from .database import StarDatabase
from .geometry import chord_angle, triple_products
from .deadline import Deadline


def pair_angle_sigma(sigma_i: np.ndarray, sigma_j: np.ndarray) -> np.ndarray:
    """
    1-sigma error of the angle between two measured directions with per-axis 1-sigma errors sigma_i.

    sigma_j [rad] (Cole & Crassidis eq. 12; sqrt(2) sigma for equal errors, eq. 14).
    """
    var_i, var_j = np.square(sigma_i), np.square(sigma_j)
    return np.sqrt(var_i + var_j + 3.0 * var_i * var_j)


def handedness_agrees(rays: np.ndarray, stars: np.ndarray, sigma: np.ndarray, beta: float) -> bool:
    """
    Mirror test for one correspondence (rays[k] <-> stars[k], (M, 3) each, M >= 3).

    The triple product of every spot triple must have the sign of its star triple's, except for
    triples so flat that noise (beta sigma times the perimeter) could flip the sign. At least one
    triple must be decisive.
    """
    m = rays.shape[0]
    idx = np.array([(i, j, k) for i in range(m) for j in range(i + 1, m) for k in range(j + 1, m)])
    r, s = rays[idx], stars[idx]
    det_spots = triple_products(r[:, 0], r[:, 1], r[:, 2])
    det_stars = triple_products(s[:, 0], s[:, 1], s[:, 2])
    perimeter = (np.linalg.norm(r[:, 0] - r[:, 1], axis=1) + np.linalg.norm(r[:, 1] - r[:, 2], axis=1)
                 + np.linalg.norm(r[:, 2] - r[:, 0], axis=1))
    decisive = np.abs(det_spots) > beta * np.max(sigma) * perimeter
    return bool(decisive.any() and np.all(np.sign(det_spots[decisive]) == np.sign(det_stars[decisive])))


def consistent_core(rays: np.ndarray, stars: np.ndarray, tolerance: np.ndarray) -> np.ndarray:
    """
    Mask of a correspondence (rays[k] <-> stars[k]) whose every pairwise angle agrees within tolerance (M, M) [rad].

    The spot with the most disagreements is dropped until none is left. A chain checks each new
    spot against one angle only, so a false star can ride along.
    """
    keep = np.ones(rays.shape[0], bool)
    misfit = np.abs(chord_angle(rays[:, None], rays[None]) - chord_angle(stars[:, None], stars[None])) / tolerance
    while True:
        bad = (misfit > 1.0) & keep[:, None] & keep[None, :]
        counts = bad.sum(axis=1)
        if counts.max() == 0:
            return keep
        worst = np.flatnonzero(counts == counts.max())
        keep[worst[np.argmax(np.where(keep, misfit, 0.0)[worst].sum(axis=1))]] = False


@dataclass(frozen=True)
class AnglePivotConfig:
    """
    pivot_limit: pivots per chain (paper: 9).

    max_solutions_per_angle: an angle with more catalog solutions is not used (paper: 10,000);
    order_by: "candidates" (fewest catalog solutions first, the paper's ideal) or "angle"
    (largest angle first, the thesis' practice); max_finalists: a chain whose finalists exceed
    this is abandoned (memory bound); max_left_out: after a chain from every angle, repeat
    leaving out each spot, then each pair of spots, ... up to this many (0: restarts only);
    starts_per_round: chains per such round (from the best-ranked angles); restart: start a new
    chain from every angle in turn (False: one chain, as in the paper); skip_empty_pivots: a
    pivot that leaves no finalist is skipped (False: the chain ends there, as in the paper).
    """

    pivot_limit: int = 9
    max_solutions_per_angle: int = 10000
    order_by: str = "candidates"
    max_finalists: int = 200000
    max_left_out: int = 2
    starts_per_round: int = 3
    restart: bool = True
    skip_empty_pivots: bool = True

    def __post_init__(self) -> None:
        bad = []
        if not (1 <= self.pivot_limit <= 1000):
            bad.append(f"pivot_limit={self.pivot_limit} must be in [1, 1000]")
        if not (1 <= self.max_solutions_per_angle <= 10**7):
            bad.append(f"max_solutions_per_angle={self.max_solutions_per_angle} must be in [1, 1e7]")
        if self.order_by not in ("candidates", "angle"):
            bad.append(f"order_by={self.order_by!r} must be 'candidates' or 'angle'")
        if not (1 <= self.max_finalists <= 10**8):
            bad.append(f"max_finalists={self.max_finalists} must be in [1, 1e8]")
        if not (0 <= self.max_left_out <= 10):
            bad.append(f"max_left_out={self.max_left_out} must be in [0, 10]")
        if not (1 <= self.starts_per_round <= 10000):
            bad.append(f"starts_per_round={self.starts_per_round} must be in [1, 10000]")
        if bad:
            raise ValueError("invalid angle-pivot config: " + "; ".join(bad))


@dataclass
class _SpotPairs:
    """
    The measured angles of one frame.

    Spot indices (first, second), angle [rad], search half-width [rad], and the k-vector
    slice [start, stop) of the catalog solutions.
    """

    first: np.ndarray
    second: np.ndarray
    angle: np.ndarray
    tolerance: np.ndarray
    start: np.ndarray
    stop: np.ndarray

    @property
    def solutions(self) -> np.ndarray:
        return self.stop - self.start


@dataclass(frozen=True)
class _Ranking:
    """
    Order of the measured angles for starting chains and choosing pivots.

    Rank (A,) angle indices best first; position (A,) each angle's place in it; usable (A,)
    angles with between 1 and max_solutions_per_angle catalog solutions.
    """

    rank: np.ndarray
    position: np.ndarray
    usable: np.ndarray


def measured_pairs(geometry: SpotGeometry, database: StarDatabase, beta: float, floor: float) -> _SpotPairs:
    """All pairs of pattern spots with their angle, beta sigma_p + floor window and catalog slice."""
    n = geometry.pattern_count
    first, second = np.triu_indices(n, k=1)
    rays = geometry.rays
    angle = chord_angle(rays[first], rays[second])
    tolerance = beta * pair_angle_sigma(geometry.sigma[first], geometry.sigma[second]) + floor
    limit = float(database.pair_angle[-1])
    keep = angle - tolerance <= limit
    first, second, angle, tolerance = first[keep], second[keep], angle[keep], tolerance[keep]
    ranges = np.array([database.kvector.range(a - t, a + t) for a, t in zip(angle, tolerance)],
                      dtype=np.int64).reshape(-1, 2)
    return _SpotPairs(first, second, angle, tolerance, ranges[:, 0], ranges[:, 1])


class AnglePivotIdentifier(StarIdentifier):
    """
    Angle method with pivoting; see the module docstring.

    stats: "chains" (chains started), "pivots" (pivots of the chain behind the latest
    hypothesis), "pivots_total", "finalists" (finalists after the first angle of that chain),
    "skipped_pivots".
    """

    name = "angle_pivot"

    def __init__(self, database: StarDatabase, config, pivot_config: AnglePivotConfig | None = None):
        super().__init__(database, config)
        self.pivot_config = pivot_config or AnglePivotConfig()

    # -- one pivot ------------------------------------------------------------------------
    def _directed_solutions(self, pairs: _SpotPairs, e: int) -> tuple[np.ndarray, np.ndarray]:
        """Catalog solutions of angle e as directed (star of first spot, star of second spot)."""
        a = self.database.pair_a[pairs.start[e]:pairs.stop[e]]
        b = self.database.pair_b[pairs.start[e]:pairs.stop[e]]
        return np.concatenate([a, b]), np.concatenate([b, a])

    def _pivot(self, finalists: np.ndarray, column: dict[int, int], pairs: _SpotPairs, e: int) -> np.ndarray:
        """
        Finalists (F, k) star arrays (column[spot] -> column) that also solve angle e.

        When angle e brings a new spot, each finalist is extended by every star its shared
        spot's star pairs with; a star is never used twice in one finalist.
        """
        u, v = int(pairs.first[e]), int(pairs.second[e])
        from_star, to_star = self._directed_solutions(pairs, e)
        if u not in column:  # orient so that u is the shared spot
            u, v = v, u
            from_star, to_star = to_star, from_star
        n_stars = self.database.star_count
        if v in column:  # closes a loop: a pure filter
            codes = np.sort(from_star.astype(np.int64) * n_stars + to_star)
            query = finalists[:, column[u]].astype(np.int64) * n_stars + finalists[:, column[v]]
            pos = np.clip(np.searchsorted(codes, query), 0, max(codes.size - 1, 0))
            hit = codes[pos] == query if codes.size else np.zeros(query.size, bool)
            return finalists[hit]
        order = np.argsort(from_star, kind="stable")
        from_star, to_star = from_star[order], to_star[order]
        shared = finalists[:, column[u]]
        lo = np.searchsorted(from_star, shared, "left")
        counts = np.searchsorted(from_star, shared, "right") - lo
        total = int(counts.sum())
        if total == 0:
            return np.zeros((0, finalists.shape[1] + 1), finalists.dtype)
        rows = np.repeat(np.arange(shared.size), counts)
        offsets = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
        new_star = to_star[np.repeat(lo, counts) + offsets]
        extended = np.column_stack([finalists[rows], new_star])
        distinct = np.all(extended[:, :-1] != new_star[:, None], axis=1)
        return extended[distinct]

    def _next_angle(self, pairs: _SpotPairs, previous: int, used: np.ndarray, excluded: set[int],
                    rank: np.ndarray) -> int | None:
        """Unused angle sharing exactly one spot with the previous angle, best rank first."""
        p, q = pairs.first[previous], pairs.second[previous]
        shares_p = (pairs.first == p) | (pairs.second == p)
        shares_q = (pairs.first == q) | (pairs.second == q)
        ok = (shares_p ^ shares_q) & ~used & (pairs.solutions <= self.pivot_config.max_solutions_per_angle)
        if excluded:
            bad = np.array(sorted(excluded))
            ok &= ~np.isin(pairs.first, bad) & ~np.isin(pairs.second, bad)
        ok &= pairs.solutions > 0
        if not ok.any():
            return None
        candidates = np.flatnonzero(ok)
        return int(candidates[np.argmin(rank[candidates])])

    # -- chains ---------------------------------------------------------------------------
    def _chain(self, pairs: _SpotPairs, start: int, rank: np.ndarray, excluded: set[int], deadline: Deadline):
        """
        Pivot from angle `start`, never using the spots in `excluded` (extended in place by spots found inconsistent).

        Returns (spots, finalists (F, k)) or None (timeout, or too many finalists).
        """
        cfg = self.pivot_config
        first, second = int(pairs.first[start]), int(pairs.second[start])
        a, b = self._directed_solutions(pairs, start)
        finalists = np.column_stack([a, b])
        column = {first: 0, second: 1}
        self.stats["finalists"] = int(finalists.shape[0])
        used = np.zeros(pairs.first.size, bool)
        used[start] = True
        previous, pivots = start, 0
        while pivots < cfg.pivot_limit:
            if finalists.shape[0] == 1 and len(column) >= 3:
                break
            if deadline.passed():
                return None
            e = self._next_angle(pairs, previous, used, excluded, rank)
            if e is None:
                break
            used[e] = True
            pivots += 1
            self.stats["pivots_total"] += 1
            narrowed = self._pivot(finalists, column, pairs, e)
            u, v = int(pairs.first[e]), int(pairs.second[e])
            new = [spot for spot in (u, v) if spot not in column]
            if narrowed.shape[0] == 0:
                # No finalist solves this angle: its new spot is suspect (false star or beyond
                # the bound); the paper stops here as inconclusive.
                if not cfg.skip_empty_pivots:
                    finalists = narrowed
                    break
                self.stats["skipped_pivots"] += 1
                excluded.update(new)
                continue
            if narrowed.shape[0] > cfg.max_finalists:
                return None
            for spot in new:
                column[spot] = len(column)
            finalists, previous = narrowed, e
        self.stats["pivots"] = pivots
        return np.array(sorted(column, key=column.get)), finalists

    def _solved_core(self, geometry: SpotGeometry, spots: np.ndarray, stars: np.ndarray):
        """
        Return the mutually consistent part of a solved chain.

        Or None if fewer than three spots remain or its handedness is mirrored.
        """
        beta = self.config.sigma_multiplier
        rays, vectors, sigma = geometry.rays[spots], self.database.vectors[stars], geometry.sigma[spots]
        tolerance = beta * pair_angle_sigma(sigma[:, None], sigma[None]) + self.config.angle_tolerance_floor_rad
        core = consistent_core(rays, vectors, tolerance)
        if core.sum() < 3 or not handedness_agrees(rays[core], vectors[core], sigma[core], beta):
            return None
        return spots[core], stars[core]

    def _completed(self, geometry: SpotGeometry, pairs: _SpotPairs, spots: np.ndarray, stars: np.ndarray,
                   excluded: set[int]) -> tuple[np.ndarray, np.ndarray]:
        """
        Return a solved core grown by every further pattern spot solved by exactly one catalog star.

        A further spot (not in `excluded`) joins when its angles to at least two spots already in
        the core are solved by exactly one catalog star; the result is checked again for
        consistency and handedness (else the core as it was). A chain stops pivoting once one
        finalist remains, so it may leave spots out, and an attitude fitted to a few clustered
        spots can put the others' stars beyond the verification radius, where the shared
        re-match cannot find them (Cole scenes: 5 of 9 stars, a poor roll). Like the pivots,
        this is attitude-independent.
        """
        column = {int(s): c for c, s in enumerate(spots)}
        finalists = stars[None, :]
        for spot in range(geometry.pattern_count):
            if spot in column or spot in excluded:
                continue
            known = np.array(list(column))
            edges = np.flatnonzero(((pairs.first == spot) & np.isin(pairs.second, known))
                                   | ((pairs.second == spot) & np.isin(pairs.first, known)))
            if edges.size < 2:
                continue  # one angle alone does not confirm a star
            trial = {**column, spot: len(column)}
            narrowed = self._pivot(finalists, column, pairs, int(edges[0]))
            for e in edges[1:]:
                if narrowed.shape[0] == 0:
                    break
                narrowed = self._pivot(narrowed, trial, pairs, int(e))
            if narrowed.shape[0] == 1:
                finalists, column = narrowed, trial
        if len(column) == spots.size:
            return spots, stars
        core = self._solved_core(geometry, np.array(sorted(column, key=column.get)), finalists[0])
        return core if core is not None and core[0].size > spots.size else (spots, stars)

    def hypotheses(self, geometry: SpotGeometry, deadline: Deadline) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        cfg = self.pivot_config
        pairs = measured_pairs(geometry, self.database, self.config.sigma_multiplier,
                               self.config.angle_tolerance_floor_rad)
        self.stats.update(chains=0, pivots=0, pivots_total=0, skipped_pivots=0, finalists=0,
                          angles=int(pairs.first.size))
        usable = (pairs.solutions > 0) & (pairs.solutions <= cfg.max_solutions_per_angle)
        if not usable.any():
            return
        # Rank: fewest solutions first, larger angle on ties (or largest angle first).
        if cfg.order_by == "candidates":
            rank = np.lexsort((-pairs.angle, pairs.solutions))
        else:
            rank = np.argsort(-pairs.angle, kind="stable")
        position = np.empty_like(rank)
        position[rank] = np.arange(rank.size)
        ranking = _Ranking(rank, position, usable)
        # Round 0 starts a chain from every angle in rank order (the paper's restarts). A spot
        # that is no catalog star (false star) kills the true finalist whenever a chain pivots
        # through it, so later rounds leave out one spot (then two, ...), the most suspect
        # first, and start from the best few angles only.
        suspicion = np.zeros(geometry.pattern_count)
        yielded: set[tuple] = set()
        for size in range(cfg.max_left_out + 1):
            if geometry.pattern_count - size < 3:
                break
            # Suspicion gathered so far orders the spots to leave out (most suspect first);
            # the faintest spot first among equals.
            suspects = np.lexsort((-np.arange(suspicion.size), -suspicion))
            starts = (None if cfg.restart else 1) if size == 0 else cfg.starts_per_round
            for left_out in itertools.combinations(suspects.tolist(), size):
                yield from self._round(geometry, pairs, ranking, set(left_out), starts, suspicion, yielded, deadline)
                if deadline.passed():
                    return

    def _round(self, geometry: SpotGeometry, pairs: _SpotPairs, ranking: _Ranking, left_out: set[int],
               starts: int | None, suspicion: np.ndarray, yielded: set,
               deadline: Deadline) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """
        Chains from the first `starts` (None: all) usable angles in rank order that avoid the spots in `left_out`.

        Yields each new solved core. `suspicion` counts, per spot, the pivots it emptied, its
        drops from a consistent core and its rejected hypotheses.
        """
        chains = 0
        for start in ranking.rank:
            if deadline.passed() or (starts is not None and chains >= starts):
                return
            if (not ranking.usable[start] or int(pairs.first[start]) in left_out
                    or int(pairs.second[start]) in left_out):
                continue
            chains += 1
            self.stats["chains"] += 1
            excluded = set(left_out)
            result = self._chain(pairs, int(start), ranking.position, excluded, deadline)
            if result is None:
                continue
            spots, finalists = result
            suspicion[list(excluded - left_out)] += 1
            if finalists.shape[0] != 1 or spots.size < 3:
                continue  # inconclusive chain
            core = self._solved_core(geometry, spots, finalists[0])
            if core is None:
                continue
            suspicion[np.setdiff1d(spots, core[0])] += 1
            spots, stars = self._completed(geometry, pairs, *core, excluded)
            key = tuple(sorted(zip(spots.tolist(), stars.tolist())))
            if key in yielded:
                continue
            yielded.add(key)
            yield spots.astype(np.int64), stars.astype(np.int64)
            suspicion[spots] += 1  # back here: verification rejected it
