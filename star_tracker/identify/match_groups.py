# SPDX-License-Identifier: Apache-2.0
"""
van Bezooijen's match-group algorithm of the Full-sky Autonomous Star Tracker (FAST, seed 002).

1. Star-pair matching: every pair of pattern spots (i, j) is compared with the guide-star pairs
   (a, b) of the k-vector whose angle agrees within t_dis = beta sigma_p + floor (sigma_p from
   Cole & Crassidis eq. 12, see angle_pivot), in both orientations. Magnitudes (criterion 2 of
   the paper, |m_i - M_a| < t_mag) are used with an unknown zero point: if both spots of a
   match lie within t_mag of the catalog magnitudes for a common zero point, their magnitude
   difference agrees within 2 t_mag, so a pair match must satisfy
       |(m_i - m_j) - (M_a - M_b)| <= 2 t_mag;
   applied to every pair of a validated group this makes all its zero-point offsets M - m lie
   within a 2 t_mag window, with no zero point to estimate. Spots without a magnitude (NaN)
   skip the test.
2. Each match (spot i, star a) is the kernel of a match group whose associated matches (j, b)
   come from the pair matches containing it; its confirmation value is the number of distinct
   spots j that confirm it.
3. Threshold: a group of n matches needs at least n kernels with confirmation >= n - 1; the
   largest such n sets ICLIM = n - 1 - ICMAXR, and only kernels above it are processed. When
   no unambiguous group results, the threshold is lowered by one, down to groups of three.
4. Validation: the associated matches of a kernel must agree pairwise (angle within the relaxed
   tolerance t_dis1, distinct spots and stars) and with the kernel's handedness (sign of the
   triple product, the paper's mirror-image test on the cross product of a and b); the largest
   mutually consistent set (a maximum clique, the paper's group "splitting") forms the group.
   Associates whose own confirmation is below 2 are dropped (the paper's adjustment for
   eliminated kernels, taken at the lowest threshold so that each kernel is validated once);
   the clique search sees the 64 best-confirmed associates.
5. Identical groups found from different kernels are merged; the largest group wins when it is
   unique or when all largest groups share at least two matches. Ties are ordered by the
   paper's quality index, the sum of the angle differences over the group's pairs (here each
   divided by its tolerance). If no threshold gives an unambiguous answer, all groups are
   offered best first (the paper's ISWPR "select the best match group" mode).

Groups are yielded as hypotheses; the shared verification decides.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, NamedTuple

import numpy as np
from numba import njit

from .angle_pivot import pair_angle_sigma
from .base import StarIdentifier
from .spot_geometry import SpotGeometry
from .database import StarDatabase
from .geometry import angle_between, chord2_rows, chord_angle, triple_product
from .deadline import Deadline

MAX_ASSOCIATES = 64  # bitmask width of the clique search
VALIDATION_CHUNK = 4096  # kernels validated between two deadline checks
SWEEP_CHUNK = 200_000  # guide pairs swept between two deadline checks


@dataclass(frozen=True)
class MatchGroupConfig:
    """
    magnitude_tolerance.

    t_mag [mag] (paper, FAST: 0.77 for 0.3 mag errors); relaxed_factor: t_dis1 / t_dis for
    validation (paper's refined SIRTF case: 4.67 / 3.78); icmaxr: ICMAXR >= 1, how far below the
    largest possible group the first threshold lies; select_best: offer groups best first when no
    threshold is unambiguous (paper's ISWPR != 1).
    """

    magnitude_tolerance: float = 0.77
    relaxed_factor: float = 1.25
    icmaxr: int = 1
    select_best: bool = True

    def __post_init__(self) -> None:
        bad = []
        if not (0 < self.magnitude_tolerance <= 20):
            bad.append(f"magnitude_tolerance={self.magnitude_tolerance} must be in (0, 20]")
        if not (1.0 <= self.relaxed_factor <= 5.0):
            bad.append(f"relaxed_factor={self.relaxed_factor} must be in [1, 5]")
        if not (1 <= self.icmaxr <= 100):
            bad.append(f"icmaxr={self.icmaxr} must be in [1, 100]")
        if bad:
            raise ValueError("invalid match-group config: " + "; ".join(bad))


class PairSweep(NamedTuple):
    """
    What the compiled sweeps over pair matches read.

    Spot pairs (pair_i, pair_j) (P,) with their guide-pair windows [start, stop) (P,) into
    (guide_a, guide_b); spot_mag (n,) and star_mag (N,) magnitudes [mag] (NaN: unknown);
    mag_limit: largest accepted difference of magnitude differences [mag].
    """

    pair_i: np.ndarray
    pair_j: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    guide_a: np.ndarray
    guide_b: np.ndarray
    spot_mag: np.ndarray
    star_mag: np.ndarray
    mag_limit: float


class Associates(NamedTuple):
    """
    Associated matches of the kernels.

    Counts (K + 1,) (filled at k + 1 while counting), fill (K,) next write position of each
    kernel, spots and stars (A,) the matches.
    """

    counts: np.ndarray
    fill: np.ndarray
    spots: np.ndarray
    stars: np.ndarray


# -- compiled inner loops -------------------------------------------------------------------

@njit(cache=True)
def _magnitudes_agree(m_i, m_j, mag_a, mag_b, limit):
    if np.isnan(m_i) or np.isnan(m_j):
        return True
    return abs((m_i - m_j) - (mag_a - mag_b)) <= limit


@njit(cache=True)
def _confirm(p0, p1, sweep, conf, last):
    """
    Add to conf (n_spots, n_stars) the confirmations by spot pairs p0..p1-1 of PairSweep `sweep`.

    A match (spot, star) is confirmed once per other spot whose pair with it matches a guide
    pair containing the star. last[spot, star] holds the last confirming spot pair. Returns the
    number of oriented pair matches that passed the magnitude test.
    """
    pair_i, pair_j, start, stop, guide_a, guide_b, spot_mag, star_mag, mag_limit = sweep
    passed = 0
    for p in range(p0, p1):
        i, j = pair_i[p], pair_j[p]
        for g in range(start[p], stop[p]):
            for flip in range(2):
                a = guide_a[g] if flip == 0 else guide_b[g]
                b = guide_b[g] if flip == 0 else guide_a[g]
                if not _magnitudes_agree(spot_mag[i], spot_mag[j], star_mag[a], star_mag[b], mag_limit):
                    continue
                passed += 1
                if last[i, a] != p:
                    last[i, a] = p
                    conf[i, a] += 1
                if last[j, b] != p:
                    last[j, b] = p
                    conf[j, b] += 1
    return passed


@njit(cache=True)
def _collect(p0, p1, sweep, conf, kernel_id, min_conf, counting, out):
    """
    Collect the associated matches (spot, star) of the kernels numbered in kernel_id (-1: not a kernel).

    From spot pairs p0..p1-1 of PairSweep `sweep`: counted into out.counts[k + 1] (counting) or
    written at out.fill[k] (Associates). Associates whose own confirmation is below min_conf
    cannot be in a group of min_conf + 1 and are left out (the paper's adjustment for
    eliminated kernels).
    """
    pair_i, pair_j, start, stop, guide_a, guide_b, spot_mag, star_mag, mag_limit = sweep
    counts, fill, spots, stars = out
    for p in range(p0, p1):
        i, j = pair_i[p], pair_j[p]
        for g in range(start[p], stop[p]):
            for flip in range(2):
                a = guide_a[g] if flip == 0 else guide_b[g]
                b = guide_b[g] if flip == 0 else guide_a[g]
                if conf[i, a] < min_conf or conf[j, b] < min_conf:
                    continue
                if not _magnitudes_agree(spot_mag[i], spot_mag[j], star_mag[a], star_mag[b], mag_limit):
                    continue
                for side in range(2):
                    ks, kt, s_, t_ = (i, a, j, b) if side == 0 else (j, b, i, a)
                    k = kernel_id[ks, kt]
                    if k < 0:
                        continue
                    if counting:
                        counts[k + 1] += 1
                    else:
                        spots[fill[k]] = s_
                        stars[fill[k]] = t_
                        fill[k] += 1


@njit(cache=True)
def _rank_associates(offsets, spots, stars, conf, keep):
    """
    Put the best-confirmed associates of every kernel with more than `keep` first.

    The clique search sees only the first `keep`.
    """
    for k in range(offsets.size - 1):
        lo, hi = offsets[k], offsets[k + 1]
        if hi - lo > keep:
            score = np.empty(hi - lo, np.int64)
            for e in range(lo, hi):
                score[e - lo] = -conf[spots[e], stars[e]]
            order = np.argsort(score, kind="mergesort")
            spots[lo:hi] = spots[lo:hi][order]
            stars[lo:hi] = stars[lo:hi][order]


@njit(cache=True)
def _popcount(x):
    n = 0
    while x:
        x &= x - np.uint64(1)
        n += 1
    return n


@njit(cache=True)
def _relaxed_chord_bounds(spot_angle, relaxed):
    """
    Squared chord bounds (n, n) each of the relaxed angle windows spot_angle +- relaxed [rad].

    A cheap first test on a star pair.
    """
    n_spots = spot_angle.shape[0]
    chord2_lo = np.empty((n_spots, n_spots))
    chord2_hi = np.empty((n_spots, n_spots))
    for x in range(n_spots):
        for y in range(n_spots):
            lo_angle = max(spot_angle[x, y] - relaxed[x, y], 0.0)
            hi_angle = min(spot_angle[x, y] + relaxed[x, y], np.pi)
            chord2_lo[x, y] = (2.0 * np.sin(0.5 * lo_angle)) ** 2
            chord2_hi[x, y] = (2.0 * np.sin(0.5 * hi_angle)) ** 2
    return chord2_lo, chord2_hi


@njit(cache=True)
def _consistency_graph(k, n, kernels, frame, vectors, beta, chord2_lo, chord2_hi):
    """
    For kernel k and its first n associates.

    Adj (n,) bitmasks of the associate pairs that agree (relaxed angle, distinct spots and
    stars, the kernel's handedness wherever noise cannot flip it), cost (n, n) their |angle
    difference| / tolerance, and base (n,) each associate's own with the kernel.
    """
    one = np.uint64(1)
    rays, sigma, spot_angle = frame.rays, frame.sigma, frame.spot_angle
    tolerance, relaxed = frame.tolerance, frame.relaxed
    lo = kernels.offsets[k]
    i, a = kernels.spot[k], kernels.star[k]
    assoc_spot, assoc_star = kernels.assoc_spot, kernels.assoc_star
    adj = np.zeros(n, np.uint64)
    cost = np.zeros((n, n))
    base = np.zeros(n)
    for p in range(n):
        jp, bp = assoc_spot[lo + p], assoc_star[lo + p]
        base[p] = abs(angle_between(vectors[a], vectors[bp]) - spot_angle[i, jp]) / tolerance[i, jp]
    for p in range(n):
        jp, bp = assoc_spot[lo + p], assoc_star[lo + p]
        for q in range(p + 1, n):
            jq, bq = assoc_spot[lo + q], assoc_star[lo + q]
            if jp == jq or bp == bq:
                continue
            chord2 = chord2_rows(vectors, bp, bq)
            if chord2 < chord2_lo[jp, jq] or chord2 > chord2_hi[jp, jq]:
                continue
            miss = abs(angle_between(vectors[bp], vectors[bq]) - spot_angle[jp, jq])
            if miss > relaxed[jp, jq]:
                continue
            det_spots = triple_product(rays[i], rays[jp], rays[jq])
            perimeter = spot_angle[i, jp] + spot_angle[i, jq] + spot_angle[jp, jq]
            margin = beta * max(sigma[i], max(sigma[jp], sigma[jq])) * perimeter
            det_stars = triple_product(vectors[a], vectors[bp], vectors[bq])
            if abs(det_spots) > margin and det_spots * det_stars < 0.0:
                continue  # mirror image
            adj[p] |= one << np.uint64(q)
            adj[q] |= one << np.uint64(p)
            cost[p, q] = cost[q, p] = miss / tolerance[jp, jq]
    return adj, cost, base


@njit(cache=True)
def _largest_clique(n, adj, cost, base):
    """
    Return the largest set of mutually agreeing associates (adjacency bitmasks adj (n,), n <= 64).

    By branch and bound over (chosen, allowed) bitmasks, depth first; among equal sizes (of real
    groups, >= 2 associates) the lowest quality index, the sum of base over the members and
    cost over their pairs. Returns (member bitmask, size, quality).
    """
    one = np.uint64(1)
    stack_chosen = np.zeros(n + 2, np.uint64)
    stack_allowed = np.zeros(n + 2, np.uint64)
    all_bits = np.uint64(0xFFFFFFFFFFFFFFFF) if n == 64 else (one << np.uint64(n)) - one
    top = 0
    stack_chosen[0], stack_allowed[0] = np.uint64(0), all_bits
    found, found_size, found_quality = np.uint64(0), 0, np.inf
    while top >= 0:
        chosen, allowed = stack_chosen[top], stack_allowed[top]
        top -= 1
        size = _popcount(chosen)
        if allowed == 0:
            # Equal sizes are ranked by quality only for real groups (>= 2 associates).
            if size > found_size or (size == found_size and size >= 2):
                quality = 0.0
                for p in range(n):
                    if chosen >> np.uint64(p) & one:
                        quality += base[p]
                        for q in range(p + 1, n):
                            if chosen >> np.uint64(q) & one:
                                quality += cost[p, q]
                if size > found_size or quality < found_quality:
                    found, found_size, found_quality = chosen, size, quality
            continue
        reach = size + _popcount(allowed)
        if reach < found_size or (reach == found_size and found_size < 2):
            continue
        v = np.uint64(0)
        while not (allowed >> v & one):
            v += one
        bit = one << v
        top += 1  # exclude v
        stack_chosen[top], stack_allowed[top] = chosen, allowed & ~bit
        top += 1  # include v (explored first)
        stack_chosen[top], stack_allowed[top] = chosen | bit, allowed & adj[v]
    return found, found_size, found_quality


@njit(cache=True)
def _validate(selected, kernels, frame, vectors, beta):
    """
    Find the largest mutually consistent subset of each kernel's associates (at most 64, the first ones).

    Consistent: pairwise angles within the relaxed tolerance, distinct spots and stars, and the
    kernel's handedness wherever noise cannot flip it. Writes the member bitmask, the group
    size (kernel included) and the quality index (sum over the group's pairs of
    |angle difference| / tolerance; lower is better; ties in size go to the lower index) of
    the kernels listed in `selected` into kernels.mask, size, quality (_Kernels; frame: _Frame).
    """
    chord2_lo, chord2_hi = _relaxed_chord_bounds(frame.spot_angle, frame.relaxed)
    offsets = kernels.offsets
    for k in selected:
        kernels.size[k] = 1
        n = min(offsets[k + 1] - offsets[k], 64)
        if n < 2:
            continue
        adj, cost, base = _consistency_graph(k, n, kernels, frame, vectors, beta, chord2_lo, chord2_hi)
        found, found_size, found_quality = _largest_clique(n, adj, cost, base)
        kernels.mask[k] = found
        kernels.size[k] = 1 + found_size
        kernels.quality[k] = found_quality


_WARM = False


def _warm_up() -> None:
    """
    Compile (or load from the on-disk cache) the compiled loops once per process.

    Then the first identify() call does not spend its time budget on it.
    """
    global _WARM
    if _WARM:
        return
    rays = np.array([[0.0, 0.0, 1.0], [0.01, 0.0, 1.0], [0.0, 0.01, 1.0]])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    sweep = PairSweep(np.array([0, 0, 1]), np.array([1, 2, 2]), np.zeros(3, np.int64), np.ones(3, np.int64),
                      np.array([0], np.int32), np.array([1], np.int32), np.zeros(3), np.zeros(3), 1.0)
    conf, last = np.zeros((3, 3), np.int32), np.full((3, 3), -1, np.int32)
    _confirm(0, 3, sweep, conf, last)
    kernel_id = np.full((3, 3), -1, np.int64)
    kernel_id[0, 0] = 0
    associates = Associates(np.zeros(2, np.int64), np.zeros(1, np.int64), np.zeros(4, np.int32), np.zeros(4, np.int32))
    for counting in (True, False):
        _collect(0, 3, sweep, conf, kernel_id, 0, counting, associates)
    counts, _, spots, stars = associates
    _rank_associates(counts, spots, stars, conf, 0)
    angle = np.full((3, 3), 0.01)
    kernels = _Kernels(np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int32), counts, spots, stars,
                       np.zeros(1, np.uint64), np.zeros(1, np.int64), np.zeros(1))
    frame = _Frame(rays, np.full(3, 1e-5), np.zeros(3), angle, angle, angle)
    _validate(np.zeros(1, np.int64), kernels, frame, rays, 3.0)
    _WARM = True


# -- the algorithm ----------------------------------------------------------------------------

@dataclass
class _Group:
    spots: np.ndarray  # sorted spot indices
    stars: np.ndarray
    quality: float

    @property
    def size(self) -> int:
        return int(self.spots.size)

    @property
    def key(self) -> tuple:
        return tuple(zip(self.spots.tolist(), self.stars.tolist()))


class _Frame(NamedTuple):
    """
    Per-frame geometry of the pattern spots.

    Rays (n, 3) sensor frame, sigma (n,) [rad], magnitude (n,) (NaN: unknown), spot_angle (n,
    n) [rad], tolerance t_dis and relaxed t_dis1 (n, n) [rad]. A record of arrays: the
    compiled validation takes it whole.
    """

    rays: np.ndarray
    sigma: np.ndarray
    magnitude: np.ndarray
    spot_angle: np.ndarray
    tolerance: np.ndarray
    relaxed: np.ndarray


class _Kernels(NamedTuple):
    """
    Every match (spot, star) with confirmation >= 2 (a possible kernel of a group of three).

    Spot, star, conf (K,); its associated matches assoc_spot/assoc_star[offsets[k]:offsets[k+1]];
    and, once validated, its group as a bitmask over the first 64 associates, the group size (0:
    not validated) and quality index (written in place by the compiled validation).
    """

    spot: np.ndarray
    star: np.ndarray
    conf: np.ndarray
    offsets: np.ndarray
    assoc_spot: np.ndarray
    assoc_star: np.ndarray
    mask: np.ndarray
    size: np.ndarray
    quality: np.ndarray

    def group(self, k: int) -> _Group:
        lo = self.offsets[k]
        bits = int(self.mask[k])
        members = lo + np.array([p for p in range(min(self.offsets[k + 1] - lo, MAX_ASSOCIATES)) if (bits >> p) & 1],
                                dtype=np.int64)
        spots = np.concatenate([[self.spot[k]], self.assoc_spot[members]]).astype(np.int64)
        stars = np.concatenate([[self.star[k]], self.assoc_star[members]]).astype(np.int64)
        order = np.argsort(spots)
        return _Group(spots[order], stars[order], float(self.quality[k]))


class MatchGroupIdentifier(StarIdentifier):
    """
    Match-group voting (FAST); see the module docstring.

    stats: "pair_matches" (guide pairs within t_dis of a spot pair), "oriented_matches" (both
    orientations, after the magnitude test), "threshold" (initial ICLIM), "levels" (thresholds
    tried), "kernels" (match groups validated), "groups" (valid groups of >= 3, before
    merging), "largest_group".
    """

    name = "match_groups"

    def __init__(self, database: StarDatabase, config, group_config: MatchGroupConfig | None = None):
        super().__init__(database, config)
        self.group_config = group_config or MatchGroupConfig()
        self._star_magnitude = np.asarray(database.magnitude, dtype=np.float64)
        self._vectors = np.ascontiguousarray(database.vectors, dtype=np.float64)
        _warm_up()

    def hypotheses(self, geometry: SpotGeometry, deadline: Deadline) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        self.stats.update(pair_matches=0, oriented_matches=0, threshold=0, levels=0, kernels=0, groups=0,
                          largest_group=0)
        frame = self._frame(geometry)
        kernels = self._match_groups(frame, deadline)
        if kernels is None or kernels.spot.size == 0:
            return
        # Threshold: the largest n with >= n kernels of confirmation >= n - 1.
        ranked = np.sort(kernels.conf)[::-1]
        sizes = np.arange(1, ranked.size + 1)
        largest = int(sizes[ranked >= sizes - 1].max())
        threshold = max(largest - 1 - self.group_config.icmaxr, 1)
        self.stats["threshold"] = threshold
        yielded: set[tuple] = set()
        made: dict[int, _Group] = {}

        def group_of(k: int) -> _Group:
            if k not in made:
                made[k] = kernels.group(k)
            return made[k]

        for level in range(threshold, 0, -1):
            if deadline.passed():
                return
            self.stats["levels"] += 1
            if not self._validate_above(level, frame, kernels, deadline):
                return
            valid = np.flatnonzero(kernels.size >= 3)
            self.stats["groups"] = int(valid.size)
            if valid.size == 0:
                continue
            self.stats["largest_group"] = int(kernels.size[valid].max())
            # The largest groups not offered yet, best quality first.
            best, unambiguous = [], True
            for top in np.unique(kernels.size[valid])[::-1]:
                at_top = valid[kernels.size[valid] == top]
                at_top = at_top[np.argsort(kernels.quality[at_top], kind="stable")]
                best, unambiguous = self._distinct(at_top, group_of, yielded, deadline)
                if best:
                    break
            if not best or (not unambiguous and level > 1):
                continue  # ambiguous: lower the threshold first
            for group in best:
                yielded.add(group.key)
                yield group.spots, group.stars
                if deadline.passed():
                    return
        if self.group_config.select_best:
            # No threshold gave an accepted answer: every group, largest and best first.
            valid = np.flatnonzero(kernels.size >= 3)
            for k in valid[np.lexsort((kernels.quality[valid], -kernels.size[valid]))]:
                if deadline.passed():
                    return
                group = group_of(int(k))
                if group.key not in yielded:
                    yielded.add(group.key)
                    yield group.spots, group.stars

    def _frame(self, geometry: SpotGeometry) -> _Frame:
        n = geometry.pattern_count
        rays = np.ascontiguousarray(geometry.rays[:n], dtype=np.float64)
        sigma = np.ascontiguousarray(geometry.sigma[:n], dtype=np.float64)
        magnitude = (np.full(n, np.nan) if geometry.magnitude is None
                     else np.ascontiguousarray(geometry.magnitude[:n], dtype=np.float64))
        tolerance = (self.config.sigma_multiplier * pair_angle_sigma(sigma[:, None], sigma[None])
                     + self.config.angle_tolerance_floor_rad)
        return _Frame(rays, sigma, magnitude, chord_angle(rays[:, None], rays[None]), tolerance,
                      self.group_config.relaxed_factor * tolerance)

    def _match_groups(self, frame: _Frame, deadline: Deadline) -> _Kernels | None:
        """
        Run steps 1-2: star-pair matching, confirmation values, every possible kernel's associated matches.

        None when the deadline passed.
        """
        db = self.database
        n = frame.rays.shape[0]
        pair_i, pair_j = np.triu_indices(n, k=1)
        angle, tol = frame.spot_angle[pair_i, pair_j], frame.tolerance[pair_i, pair_j]
        window = np.array([db.kvector.range(a - t, a + t) for a, t in zip(angle, tol)],
                          dtype=np.int64).reshape(-1, 2)
        magnitude_limit = 2.0 * self.group_config.magnitude_tolerance  # on magnitude differences
        sweep = PairSweep(pair_i.astype(np.int64), pair_j.astype(np.int64), window[:, 0].copy(), window[:, 1].copy(),
                          db.pair_a, db.pair_b, frame.magnitude, self._star_magnitude, magnitude_limit)
        self.stats["pair_matches"] = int((window[:, 1] - window[:, 0]).sum())
        # The compiled sweeps run in chunks of spot pairs, the deadline checked between.
        matches = np.concatenate([[0], np.cumsum(window[:, 1] - window[:, 0])])
        bounds = np.unique(np.concatenate([np.searchsorted(matches, np.arange(0, matches[-1], SWEEP_CHUNK)),
                                           [pair_i.size]]))
        chunks = list(zip(bounds[:-1], bounds[1:]))

        conf = np.zeros((n, db.star_count), np.int32)
        last = np.full((n, db.star_count), -1, np.int32)
        for p0, p1 in chunks:
            if deadline.passed():
                return None
            self.stats["oriented_matches"] += int(_confirm(p0, p1, sweep, conf, last))

        spot, star = np.nonzero(conf >= 2)
        kernel_id = np.full(conf.shape, -1, np.int64)
        kernel_id[spot, star] = np.arange(spot.size)
        offsets = np.zeros(spot.size + 1, np.int64)  # counts at k + 1, then offsets
        fill = np.zeros(spot.size, np.int64)
        assoc_spot = assoc_star = np.zeros(0, np.int32)
        for counting in (True, False):
            if not counting:
                offsets = np.cumsum(offsets)
                fill = offsets[:-1].copy()
                assoc_spot, assoc_star = np.empty(offsets[-1], np.int32), np.empty(offsets[-1], np.int32)
            associates = Associates(offsets, fill, assoc_spot, assoc_star)
            for p0, p1 in chunks:
                if deadline.passed():
                    return None
                _collect(p0, p1, sweep, conf, kernel_id, 2, counting, associates)
        _rank_associates(offsets, assoc_spot, assoc_star, conf, MAX_ASSOCIATES)
        k = spot.size
        return _Kernels(spot.astype(np.int64), star.astype(np.int64), conf[spot, star], offsets, assoc_spot,
                        assoc_star, np.zeros(k, np.uint64), np.zeros(k, np.int64), np.zeros(k))

    def _validate_above(self, level: int, frame: _Frame, kernels: _Kernels, deadline: Deadline) -> bool:
        """
        Run steps 3-4: validate the kernels with confirmation > level not validated yet.

        False when the deadline passed.
        """
        fresh = np.flatnonzero((kernels.conf > level) & (kernels.size == 0))
        for chunk in range(0, fresh.size, VALIDATION_CHUNK):
            if deadline.passed():
                return False
            part = fresh[chunk:chunk + VALIDATION_CHUNK]
            _validate(part, kernels, frame, self._vectors, self.config.sigma_multiplier)
            self.stats["kernels"] += int(part.size)
        return True

    @staticmethod
    def _distinct(kernels: np.ndarray, group_of, yielded: set, deadline: Deadline) -> tuple[list[_Group], bool]:
        """
        Run step 5: the distinct groups of these kernels not yet yielded, in order.

        Also whether they are unambiguous (all share >= 2 matches); stops at the first group
        that makes them ambiguous.
        """
        found: dict[tuple, _Group] = {}
        for count, k in enumerate(kernels):
            if count % 256 == 255 and deadline.passed():
                break
            group = group_of(int(k))
            if group.key in yielded or group.key in found:
                continue
            matches = set(group.key)
            ambiguous = any(len(matches & set(other)) < 2 for other in found)
            found[group.key] = group
            if ambiguous:
                return list(found.values()), False
        return list(found.values()), True
