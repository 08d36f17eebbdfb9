# SPDX-License-Identifier: Apache-2.0
"""
Scale-free patterns: the field of view of a lost-in-space frame from the stars themselves.

`solve --fov` knows the field only roughly (+-5 %), and the pattern search (hybrid and the
others) needs it within ~0.3 %. Instead of stepping through the fields, four-star patterns are
matched by shape alone: the six angles between four stars, sorted, divided by the largest, do
not depend on the focal length (to first order: the spots' rays are computed with the nominal
one). Each match of an image pattern to a catalog pattern gives the focal length (image angle /
catalog angle) and an attitude; a quick count of the spots that land on projected guide stars
judges them, and a match is refitted over those spots (its four centroids fix the scale of
their own part of the image only: a lens' distortion, trailed stars). The caller then
identifies the frame with the algorithm's full verification at that focal length.

Catalog patterns: for circles spread evenly over the sky (radius = half the field's shorter
side), all four-star subsets of the circle's CIRCLE_STARS brightest guide stars. Image
patterns: all four-spot subsets of the IMAGE_SPOTS brightest spots. Patterns are looked up by
a hash of their five ratios in bins of RATIO_BIN.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import dataclass

import numpy as np

from ..models.attitude_estimation import svd_rotation
from ..models.camera import CameraModel
from ..models.catalog import cache_dir, load_validated_npz, save_validated_npz
from ..models.file_memo import FileMemo
from .database import StarDatabase
from .deadline import Deadline
from .verify import verify

PATTERN_FORMAT_VERSION = 1
CIRCLE_STARS = 10  # brightest guide stars per sky circle whose 4-subsets are stored
IMAGE_SPOTS = 10  # brightest spots whose 4-subsets are looked up
VERIFY_SPOTS = 40  # brightest spots counted on projected guide stars to rank a match
CIRCLE_SPACING = 0.75  # circle centres this fraction of the circle radius apart
RATIO_BIN = 0.01  # hash bin of each angle ratio
SCAN_AFTER_MATCH = 50  # image patterns looked up after the last match before the scan ends
REFINE_ROUNDS = 3  # scale and attitude refits of a pattern match over all its matched spots (_refined)
REFINE_RADIUS_FACTOR = 3.0  # the refits' match radius over the verification's
CONCLUSIVE_SHARE = 0.5  # a field this share of the VERIFY_SPOTS (or of its guide stars in view) confirm ends the scan
REFIT_SHORTFALL = 2  # a pattern match this many spots short of `need` is refitted (_refined) before it is judged
RATIO_BASE = int(round(1.0 / RATIO_BIN)) + 2
_PAIRS = np.array(list(itertools.combinations(range(4), 2)))  # the six pairs of a pattern


def _pair_angles(vectors: np.ndarray) -> np.ndarray:
    """(P, 6) angles [rad] between the four unit vectors of each of P patterns (P, 4, 3)."""
    a, b = vectors[:, _PAIRS[:, 0]], vectors[:, _PAIRS[:, 1]]
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.einsum("pkj,pkj->pk", a, b))


def pattern_shape(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Shape of patterns (P, 4, 3).

    (ratios (P, 5): the five smaller sorted pair angles over the largest; largest (P,)
    [rad]; order (P, 4): the four stars by their angle from the pattern's centroid, the
    correspondence that matching preserves).
    """
    angles = np.sort(_pair_angles(vectors), axis=1)
    largest = angles[:, 5]
    centroid = vectors.sum(axis=1)
    centroid /= np.linalg.norm(centroid, axis=1, keepdims=True)
    order = np.argsort(-np.einsum("pkj,pj->pk", vectors, centroid), axis=1, kind="stable")
    return angles[:, :5] / largest[:, None], largest, order


def ratio_keys(ratios: np.ndarray) -> np.ndarray:
    """Hash (int64) of each pattern's five ratios binned by RATIO_BIN."""
    bins = np.floor(ratios / RATIO_BIN).astype(np.int64)
    return bins @ (RATIO_BASE ** np.arange(5, dtype=np.int64))


@dataclass(frozen=True)
class PatternDatabase:
    """
    Catalog four-star patterns sorted by ratio key.

    Stars (P, 4) guide-star indices in centroid-distance order; ratios (P, 5); largest (P,)
    largest pair angle [rad]; keys (P,).
    """

    stars: np.ndarray
    ratios: np.ndarray
    largest: np.ndarray
    keys: np.ndarray
    circle_radius_rad: float


def circle_centres(spacing_rad: float) -> np.ndarray:
    """Return unit vectors spread evenly over the sphere (a Fibonacci lattice), ~spacing_rad apart."""
    count = max(12, int(math.ceil(4.0 * math.pi / spacing_rad ** 2)))
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z ** 2)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def build_patterns(database: StarDatabase, circle_radius_rad: float) -> PatternDatabase:
    """
    Return every four-subset, without repeats, of the brightest guide stars of each sky circle.

    The CIRCLE_STARS brightest of each circle of radius circle_radius_rad [rad].
    """
    from scipy.spatial import cKDTree

    tree = cKDTree(database.vectors)
    centres = circle_centres(CIRCLE_SPACING * circle_radius_rad)
    chord = 2.0 * math.sin(0.5 * circle_radius_rad)
    members = tree.query_ball_point(centres, chord)
    subsets = {k: np.array(list(itertools.combinations(range(k), 4))) for k in range(4, CIRCLE_STARS + 1)}
    rows = []
    for stars in members:
        if len(stars) < 4:
            continue
        stars = np.asarray(stars)
        brightest = np.sort(stars[np.argsort(database.magnitude[stars], kind="stable")[:CIRCLE_STARS]])
        rows.append(brightest[subsets[brightest.size]])
    if not rows:
        raise ValueError(f"no sky circle of radius {math.degrees(circle_radius_rad):.2f} deg holds four guide stars")
    stars = np.unique(np.concatenate(rows), axis=0)
    ratios, largest, order = pattern_shape(database.vectors[stars])
    stars = np.take_along_axis(stars, order, axis=1)
    keys = ratio_keys(ratios)
    by_key = np.argsort(keys, kind="stable")
    return PatternDatabase(stars[by_key].astype(np.int32), ratios[by_key].astype(np.float32),
                           largest[by_key].astype(np.float32), keys[by_key], float(circle_radius_rad))


RADIUS_STEP = 1.02  # circle radii are rounded down to a power of this: nearby fields share one file


_LOADED: FileMemo[PatternDatabase] = FileMemo(4)  # reused in the process while the file is unchanged


def load_or_build_patterns(database: StarDatabase, circle_radius_rad: float) -> PatternDatabase:
    """
    Return the pattern database for these guide stars and circles of at most circle_radius_rad [rad].

    The radius is rounded down to a power of RADIUS_STEP, so that fields a few percent apart
    share it; cached beside the pair database, and reused in the process while that file is
    unchanged (models/file_memo.py).
    """
    circle_radius_rad = RADIUS_STEP ** math.floor(math.log(circle_radius_rad) / math.log(RADIUS_STEP))
    identity = json.dumps({"pairs": database.config.identity(), "radius": round(circle_radius_rad, 6),
                           "circle_stars": CIRCLE_STARS, "spacing": CIRCLE_SPACING, "bin": RATIO_BIN,
                           "version": PATTERN_FORMAT_VERSION}, sort_keys=True)
    name = f"patterns4_{hashlib.sha256(identity.encode()).hexdigest()[:16]}.npz"
    path = (database.cache_directory or cache_dir()) / name
    loaded = _LOADED.get(path, identity)
    if loaded is not None:
        return loaded
    arrays = load_validated_npz(path)
    if arrays is not None and set(arrays) >= {"stars", "ratios", "largest", "keys"}:
        patterns = PatternDatabase(arrays["stars"], arrays["ratios"], arrays["largest"], arrays["keys"],
                                   circle_radius_rad)
        _LOADED.put(path, identity, patterns)
        return patterns
    patterns = build_patterns(database, circle_radius_rad)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_validated_npz(path, {"stars": patterns.stars, "ratios": patterns.ratios, "largest": patterns.largest,
                                  "keys": patterns.keys})
    except OSError:
        pass  # an unwritable cache costs a rebuild next time, never the patterns
    _LOADED.put(path, identity, patterns)
    return patterns


@dataclass(frozen=True)
class FieldEstimate:
    """
    A focal length found by a pattern match.

    Camera (nominal with fx, fy scaled), the attitude (sensor -> ICRS) of the match, the
    spots that landed on guide stars, and the guide stars it projects into the image.
    """

    camera: CameraModel
    rotation: np.ndarray
    matched: int
    stars_in_view: int = 0  # guide stars projected into the image at that field and attitude


def scaled_camera(camera: CameraModel, scale: float) -> CameraModel:
    return CameraModel(camera.width, camera.height, camera.fx * scale, camera.fy * scale, camera.cx, camera.cy,
                       tuple(camera.distortion))


def _refined(estimate: FieldEstimate, spots, check: np.ndarray, database: StarDatabase, radius_px: float,
             rounds: int = REFINE_ROUNDS) -> FieldEstimate:
    """
    Return the estimate with its scale and attitude fitted to all the spots `check` it matched.

    A four-star pattern's scale is as good as its four centroids (trailed stars: 1 % off on a
    real 27 deg frame, so that its edge stars miss their radius and the attitude fails
    verification): the scale is refitted by least squares over every pair of matched stars'
    angles (image angle at the estimate's focal length over catalog angle, as for the
    pattern), the attitude by SVD, and the spots matched again, while the matches grow.
    """
    for _ in range(rounds):
        # Matched within REFINE_RADIUS_FACTOR x the radius: a scale 1 % off puts the edge stars
        # beyond the radius itself, and a fit to the centre's stars alone keeps the error.
        matches = verify(estimate.rotation, spots.x[check], spots.y[check], database, estimate.camera,
                         REFINE_RADIUS_FACTOR * radius_px)
        if matches.spot_index.size < max(estimate.matched, 3):
            break
        stars = database.vectors[matches.star_index]
        rays = estimate.camera.pixel_to_ray(spots.x[check[matches.spot_index]], spots.y[check[matches.spot_index]])
        upper = np.triu_indices(stars.shape[0], 1)
        catalog_angle = np.arccos(np.clip((stars @ stars.T)[upper], -1.0, 1.0))
        image_angle = np.arccos(np.clip((rays @ rays.T)[upper], -1.0, 1.0))
        scale = float(image_angle @ catalog_angle / (catalog_angle @ catalog_angle))
        camera = scaled_camera(estimate.camera, scale)
        rays = camera.pixel_to_ray(spots.x[check[matches.spot_index]], spots.y[check[matches.spot_index]])
        rotation = svd_rotation(rays, stars)
        result = verify(rotation, spots.x[check], spots.y[check], database, camera, radius_px)
        if result.spot_index.size <= estimate.matched:
            break
        estimate = FieldEstimate(camera, rotation, int(result.spot_index.size), result.stars_in_view)
    return estimate


def estimate_fields(spots, camera: CameraModel, database: StarDatabase, patterns: PatternDatabase,
                    tolerance: float, deadline: Deadline, ratio_tolerance: float = 0.01,
                    radius_px: float = 3.0, max_estimates: int = 3) -> list[FieldEstimate]:
    """
    Return focal lengths within +-tolerance (fraction) of `camera`'s at which brightest-spot patterns match.

    Matching catalog patterns, each refitted over the spots it matched (_refined; those within
    REFIT_SHORTFALL of `need` too), best first (most spots on guide stars), distinct to 0.2 %,
    at most max_estimates; the scan ends SCAN_AFTER_MATCH image patterns after the last new
    field (a better match comes within ~40 on the real corpus; the rest of the 210 only cost
    time), or at a field that CONCLUSIVE_SHARE of the VERIFY_SPOTS (or of the guide stars in
    view, if fewer) confirm. Empty when nothing matched before `deadline`.
    """
    n = min(len(spots), IMAGE_SPOTS)
    if n < 4:
        return []
    brightest = np.argsort(-spots.flux, kind="stable")[:n]
    rays = camera.pixel_to_ray(spots.x[brightest], spots.y[brightest])
    subsets = np.array(list(itertools.combinations(range(n), 4)))
    ratios, largest, order = pattern_shape(rays[subsets])
    subsets = np.take_along_axis(subsets, order, axis=1)
    check = np.argsort(-spots.flux, kind="stable")[:VERIFY_SPOTS]
    need = min(7, len(spots))  # the pattern's four and at least three more
    found: list[FieldEstimate] = []
    known_fx: list[float] = []  # focal lengths [px] of the matches so far, as patterns gave them and refined
    last_match = 0
    lo_scale, hi_scale = 1.0 / (1.0 + tolerance), 1.0 / (1.0 - tolerance)
    # Hash keys of an image pattern: its own bin and, per ratio within ratio_tolerance of a bin
    # edge, the neighbour bin (offsets -1/0/+1 per ratio), in increasing key order (no repeats).
    offsets = np.array(list(itertools.product((-1, 0, 1), repeat=5)), np.int64)
    weights = RATIO_BASE ** np.arange(5, dtype=np.int64)
    by_key = np.argsort(offsets @ weights)
    offsets = offsets[by_key]
    offset_keys = offsets @ weights
    lower, upper = offsets < 0, offsets > 0
    for p in range(subsets.shape[0]):
        if deadline.passed() or (found and p - last_match > SCAN_AFTER_MATCH):
            break
        base = np.floor(ratios[p] / RATIO_BIN).astype(np.int64)
        near = ((offsets == 0) | (lower & (ratios[p] - ratio_tolerance < base * RATIO_BIN))
                | (upper & (ratios[p] + ratio_tolerance >= (base + 1) * RATIO_BIN))).all(axis=1)
        keys = base @ weights + offset_keys[near]
        first = np.searchsorted(patterns.keys, keys, side="left")
        last = np.searchsorted(patterns.keys, keys, side="right")
        hit = last > first
        if not hit.any():
            continue
        cand = np.concatenate([np.arange(a, b) for a, b in zip(first[hit], last[hit])])
        # f_true / f_nominal = image angle (rays of the nominal focal length) / catalog angle.
        scale = largest[p] / patterns.largest[cand]
        close = np.all(np.abs(patterns.ratios[cand] - ratios[p]) <= ratio_tolerance, axis=1)
        keep = close & (scale >= lo_scale) & (scale <= hi_scale)
        cand, scale = cand[keep], scale[keep]
        for c, s in zip(cand, scale):
            # Near a field found (its refined focal length, or the pattern scale that led to it): nothing new.
            if any(abs(s * camera.fx / fx - 1.0) < 2e-3 for fx in known_fx):
                continue
            trial = scaled_camera(camera, float(s))
            spot_idx = brightest[subsets[p]]
            body = trial.pixel_to_ray(spots.x[spot_idx], spots.y[spot_idx])
            rotation = svd_rotation(body, database.vectors[patterns.stars[c]])
            result = verify(rotation, spots.x[check], spots.y[check], database, trial, radius_px)
            matched = result.spot_index.size
            # A pattern in a distorted part of the image has the scale of that part: its attitude
            # puts only the spots around it within the radius; refitted over those, the rest follow.
            if matched >= need - REFIT_SHORTFALL:
                refined = _refined(FieldEstimate(trial, rotation, int(matched), result.stars_in_view), spots, check,
                                   database, radius_px)
                if refined.matched < need:
                    continue
                known_fx += [trial.fx, refined.camera.fx]
                same = [i for i, e in enumerate(found) if abs(refined.camera.fx / e.camera.fx - 1.0) < 2e-3]
                if not same:
                    found.append(refined)
                    last_match = p
                elif refined.matched > found[same[0]].matched:  # two patterns, one field: the better fit
                    found[same[0]] = refined
        # Enough fields, or one that most of the brightest spots (or guide stars in view) confirm: the scan is over.
        if len(found) >= max_estimates or any(e.matched >= CONCLUSIVE_SHARE * min(check.size, e.stars_in_view)
                                              for e in found):
            break
    return sorted(found, key=lambda e: -e.matched)
