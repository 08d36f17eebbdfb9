# SPDX-License-Identifier: Apache-2.0
"""
Triangle features (Cole & Crassidis spherical, Toloei planar) and the catalog triangle database.

The features are checked against independent computations.
"""
import numpy as np
import pytest

from star_tracker.models.catalog import load_validated_npz, save_validated_npz
from star_tracker.identify import DatabaseConfig, load_or_build_database
from star_tracker.identify import triangle_database
from star_tracker.identify.guide_triangles import count_triangles, sky_cells
from star_tracker.identify.triangle_database import (TriangleConfig, build_triangle_database, load_or_build_triangles,
                                                     select_guide_stars, triangle_cache_path)
from star_tracker.identify.triangle_features import (measured_features, planar_area, planar_polar_moment,
                                                     spherical_area, spherical_area_jacobian, spherical_polar_moment,
                                                     spherical_polar_moment_fast, triangle_sides)
from star_tracker.identify.triangle_matching import match_triangles


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_triangles(rng, n, spread):
    """Return n random small triangles around random centres, vertex scatter `spread` [rad]."""
    centre = unit(rng.normal(size=(n, 3)))
    return [unit(centre + rng.normal(scale=spread, size=(n, 3))) for _ in range(3)]


def excess_area(v1, v2, v3):
    """Independent spherical area: Van Oosterom & Strackee's triple-product formula."""
    det = np.abs(np.einsum("ni,ni->n", v1, np.cross(v2, v3)))
    dots = 1 + np.einsum("ni,ni->n", v1, v2) + np.einsum("ni,ni->n", v2, v3) + np.einsum("ni,ni->n", v3, v1)
    return 2 * np.arctan2(det, dots)


def recursive_moment(v1, v2, v3, depth, centre=None):
    """Independent, literal transcription of Cole's recursion (thesis E.47)."""
    if centre is None:
        centre = unit(v1 + v2 + v3)
    if depth == 0:
        leaf = unit(v1 + v2 + v3)
        theta = np.arccos(np.clip(leaf @ centre, -1, 1))
        return theta**2 * excess_area(v1[None], v2[None], v3[None])[0]
    m12, m23, m31 = unit(v1 + v2), unit(v2 + v3), unit(v3 + v1)
    return sum(recursive_moment(a, b, c, depth - 1, centre)
               for a, b, c in ((v1, m12, m31), (v2, m12, m23), (v3, m23, m31), (m12, m23, m31)))


def test_spherical_area_of_the_octant_and_against_the_triple_product_formula():
    octant = spherical_area(np.full((1, 3), np.pi / 2))
    assert octant[0] == pytest.approx(np.pi / 2, rel=1e-12)
    rng = np.random.default_rng(1)
    v1, v2, v3 = random_triangles(rng, 500, 0.05)
    sides = triangle_sides(v1, v2, v3)
    np.testing.assert_allclose(spherical_area(sides), excess_area(v1, v2, v3), rtol=1e-8, atol=1e-15)


def test_area_jacobian_matches_finite_differences():
    rng = np.random.default_rng(2)
    v1, v2, v3 = random_triangles(rng, 50, 0.05)
    sides = triangle_sides(v1, v2, v3)
    sides = sides[spherical_area(sides) > 0.1 * sides.max(axis=1) ** 2]  # not degenerate (singular)
    jac = spherical_area_jacobian(sides)
    h = 1e-7
    for k in range(3):
        up, down = sides.copy(), sides.copy()
        up[:, k] += h
        down[:, k] -= h
        numeric = (spherical_area(up) - spherical_area(down)) / (2 * h)
        np.testing.assert_allclose(jac[:, k], numeric, rtol=1e-5, atol=1e-9)


@pytest.mark.slow  # ~7 s
def test_polar_moment_matches_the_literal_recursion_and_converges_with_depth():
    rng = np.random.default_rng(3)
    v1, v2, v3 = random_triangles(rng, 5, 0.04)
    for depth in (1, 2, 3):
        ours = spherical_polar_moment(v1, v2, v3, depth)
        literal = [recursive_moment(a, b, c, depth) for a, b, c in zip(v1, v2, v3)]
        np.testing.assert_allclose(ours, literal, rtol=1e-9)
        # The vectorized catalog path agrees with the exact one.
        np.testing.assert_allclose(spherical_polar_moment_fast(v1, v2, v3, depth), ours, rtol=1e-7)
    values = np.array([spherical_polar_moment(v1, v2, v3, d) for d in range(1, 7)])
    steps = np.abs(np.diff(values, axis=0))
    assert np.all(steps[1:] < 0.5 * steps[:-1])  # midpoint rule: error falls ~4x per level
    # The limit is the planar polar moment of a small triangle, A (a^2+b^2+c^2) / 36.
    planar = planar_polar_moment(triangle_sides(v1, v2, v3))
    np.testing.assert_allclose(values[-1], planar, rtol=5e-3)


def test_planar_features_against_heron_and_monte_carlo_integration():
    sides = np.array([[3.0, 4.0, 5.0]])
    assert planar_area(sides)[0] == pytest.approx(6.0)
    assert planar_polar_moment(sides)[0] == pytest.approx(6.0 * 50.0 / 36.0)
    # Polar moment about the centroid by sampling the triangle (0,0), (4,0), (0,3).
    rng = np.random.default_rng(4)
    u, v = rng.uniform(size=(2, 400_000))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    x, y = 4 * u, 3 * v
    integral = 6.0 * np.mean((x - 4 / 3) ** 2 + (y - 1.0) ** 2)
    assert integral == pytest.approx(planar_polar_moment(sides)[0], rel=5e-3)


@pytest.mark.parametrize("spherical", [True, False])
def test_feature_sigmas_match_monte_carlo(spherical):
    """
    Check the linearized 1-sigma of area, moment and side product against a Monte-Carlo scatter.

    beta = 1, no floor; the scatter of noisy measurements of the same triangle.
    """
    rng = np.random.default_rng(5 if spherical else 6)
    v1, v2, v3 = (v[0] for v in random_triangles(rng, 1, 0.04))
    sigma = 2e-5
    clean = measured_features(np.array([v1, v2, v3]), np.full(3, sigma), np.array([[0, 1, 2]]), spherical,
                              beta=1.0, floor=0.0)
    trials = 3000
    rays = np.concatenate([unit(v + rng.normal(scale=sigma, size=(trials, 3))) for v in (v1, v2, v3)])
    triples = np.column_stack([np.arange(trials), trials + np.arange(trials), 2 * trials + np.arange(trials)])
    noisy = measured_features(rays, np.full(3 * trials, sigma), triples, spherical, beta=1.0, floor=0.0)
    for value, tol in (("area", "area_tol"), ("moment", "moment_tol"), ("product", "product_tol")):
        scatter = np.std(getattr(noisy, value))
        assert getattr(clean, tol)[0] == pytest.approx(scatter, rel=0.12), value
    # Sides: sqrt(s_i^2 + s_j^2).
    np.testing.assert_allclose(np.std(noisy.sides, axis=0), clean.side_tol[0], rtol=0.1)


@pytest.fixture(scope="module")
def small_database():
    return load_or_build_database(DatabaseConfig(magnitude_limit=4.5, max_pair_angle_rad=float(np.radians(12.0))))


def brute_force_triangles(database, stars, max_side):
    """All triples with pairwise angles <= max_side, from the dense angle matrix."""
    v = database.vectors[stars]
    close = np.arccos(np.clip(v @ v.T, -1, 1)) <= max_side
    found = set()
    for i, j in zip(*np.nonzero(np.triu(close, 1))):
        for k in np.flatnonzero(close[i] & close[j]):
            if k > j:
                found.add((int(stars[i]), int(stars[j]), int(stars[k])))
    return found


def test_database_holds_exactly_the_triangles_with_short_sides(small_database, tmp_path):
    config = TriangleConfig(max_side_rad=float(np.radians(10.0)))
    triangles = load_or_build_triangles(small_database, config, tmp_path)
    assert triangles.cells_per_face == 0 and triangles.guide_stars.size == small_database.star_count
    expected = brute_force_triangles(small_database, np.arange(small_database.star_count), config.max_side_rad)
    for index in (triangles.spherical, triangles.planar):
        rows = index.stars.astype(np.int64)
        assert np.all(rows[:, 0] < rows[:, 1]) and np.all(rows[:, 1] < rows[:, 2])
        assert set(map(tuple, rows.tolist())) == expected
    # Stored features equal a fresh computation.
    index = triangles.spherical
    v1, v2, v3 = (small_database.vectors[index.stars[:, k]] for k in range(3))
    sides = triangle_sides(v1, v2, v3)
    np.testing.assert_allclose(index.area, excess_area(v1, v2, v3), rtol=1e-5)
    np.testing.assert_allclose(index.moment, spherical_polar_moment(v1, v2, v3, config.moment_depth), rtol=1e-5)
    np.testing.assert_allclose(index.product, np.prod(sides, axis=1), rtol=1e-5)
    # Blocks: areas ascending from block to block, moments ascending within a block.
    assert np.all(index.block_min[1:] >= index.block_max[:-1])
    blocks = np.arange(index.area.size) // index.block
    same = blocks[1:] == blocks[:-1]
    assert np.all(np.diff(index.moment)[same] >= 0)
    planar = triangles.planar
    pv = [small_database.vectors[planar.stars[:, k]] for k in range(3)]
    np.testing.assert_allclose(planar.area, planar_area(triangle_sides(*pv)), rtol=1e-5)


def test_cache_round_trip_and_rebuild_of_a_damaged_file(small_database, tmp_path):
    config = TriangleConfig(max_side_rad=float(np.radians(9.0)))
    built = build_triangle_database(small_database, config)
    assert built.build_seconds > 0 and built.nbytes > 0
    first = load_or_build_triangles(small_database, config, tmp_path)
    path = triangle_cache_path(small_database, config, tmp_path)
    assert path.is_file() and path.stat().st_size >= 0.9 * first.nbytes
    triangle_database._MEMO.clear()
    loaded = load_or_build_triangles(small_database, config, tmp_path)
    for name in ("stars", "area", "moment", "product", "block_min", "block_max"):
        np.testing.assert_array_equal(getattr(loaded.spherical, name), getattr(built.spherical, name))
        np.testing.assert_array_equal(getattr(loaded.planar, name), getattr(built.planar, name))
    np.testing.assert_array_equal(loaded.spherical.kvector.k, built.spherical.kvector.k)
    # Another parameter set is another file.
    other = TriangleConfig(max_side_rad=float(np.radians(9.0)), moment_depth=2)
    assert other.cache_key(small_database) != config.cache_key(small_database)
    # A damaged file is rebuilt, not trusted.
    triangle_database._MEMO.clear()
    path.write_bytes(path.read_bytes()[:-100])
    rebuilt = load_or_build_triangles(small_database, config, tmp_path)
    np.testing.assert_array_equal(rebuilt.spherical.stars, built.spherical.stars)
    # A checksum-valid file that this code did not write for this database (star indices out of
    # range would make the compiled search read outside its arrays; wrong shapes) is rebuilt too.
    arrays = load_validated_npz(path)
    tampered = {"star index out of range": {**arrays,
                                            "planar_stars": arrays["planar_stars"] + small_database.star_count},
                "guide star out of range": {**arrays, "guide_stars": arrays["guide_stars"] - 10**6},
                "short column": {**arrays, "spherical_area": arrays["spherical_area"][:-1]},
                "flat stars": {**arrays, "spherical_stars": arrays["spherical_stars"].ravel()}}
    for name, content in tampered.items():
        triangle_database._MEMO.clear()
        save_validated_npz(path, content)
        rebuilt = load_or_build_triangles(small_database, config, tmp_path)
        np.testing.assert_array_equal(rebuilt.planar.stars, built.planar.stars, err_msg=name)
        np.testing.assert_array_equal(rebuilt.spherical.area, built.spherical.area, err_msg=name)


def test_thinning_keeps_the_brightest_stars_per_cell_within_the_budget(small_database):
    config = TriangleConfig(max_side_rad=float(np.radians(12.0)), max_triangles=3000, stars_per_cell=2)
    guide, cells = select_guide_stars(small_database, config)
    assert 1 <= cells < 256 and guide.size < small_database.star_count
    assert count_triangles(small_database, guide, config.max_side_rad) <= config.max_triangles
    cell = sky_cells(small_database.vectors, cells)
    kept = np.zeros(small_database.star_count, bool)
    kept[guide] = True
    for c in np.unique(cell):
        members = np.flatnonzero(cell == c)
        assert kept[members].sum() == min(2, members.size)
        if (~kept[members]).any():  # every dropped star is fainter than every kept one
            assert small_database.magnitude[members[kept[members]]].max() <= small_database.magnitude[
                members[~kept[members]]].min()


def test_sky_cells_cover_the_sphere_evenly():
    rng = np.random.default_rng(7)
    cells = sky_cells(unit(rng.normal(size=(200_000, 3))), 8)
    counts = np.bincount(cells, minlength=6 * 64)
    assert counts.size == 6 * 64 and counts.min() > 0
    assert counts.max() / counts.min() < 1.6  # equal-angle cube: areas within ~1.4


def test_matching_finds_a_catalog_triangle_with_its_vertex_order_and_not_its_mirror(small_database, tmp_path):
    config = TriangleConfig(max_side_rad=float(np.radians(10.0)))
    triangles = load_or_build_triangles(small_database, config, tmp_path)
    rng = np.random.default_rng(8)
    sigma = 3e-5
    for spherical in (True, False):
        for row in rng.choice(triangles.triangle_count, 10, replace=False):
            stars = triangles.spherical.stars[row].astype(np.int64)[rng.permutation(3)]
            rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            rays = unit(small_database.vectors[stars] @ rotation + rng.normal(scale=sigma, size=(3, 3)))
            features = measured_features(rays, np.full(3, sigma), np.array([[0, 1, 2]]), spherical,
                                         beta=3.0, floor=1e-5)
            found = match_triangles(triangles, small_database, features, spherical, cap=100)
            assert any(np.array_equal(s, stars) for s in found.stars)
            assert found.area_candidates[0] >= found.finalists[0] >= 1
            mirrored = rays * np.array([-1.0, 1.0, 1.0])
            features = measured_features(mirrored, np.full(3, sigma), np.array([[0, 1, 2]]), spherical,
                                         beta=3.0, floor=1e-5)
            if features.handedness[0] == 0:
                continue  # too flat for a handedness decision
            found = match_triangles(triangles, small_database, features, spherical, cap=100)
            assert not any(set(s) == set(stars) for s in found.stars.tolist())
