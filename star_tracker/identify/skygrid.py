# SPDX-License-Identifier: Apache-2.0
"""
Cube-map grid over the celestial sphere: O(1) lookup of the catalog stars near a direction.

Each unit vector belongs to the cube face of its largest component and to one of G x G
cells of that face (gnomonic coordinates u, v in [-1, 1]). Stars are stored sorted by cell,
so a cell's stars are `star_of_cell[cell_start[c]:cell_start[c + 1]]`. A cone of radius r
around p maps into the face's (u, v) box p_uv +- d with d = r (1 + u^2 + v^2) (the largest
stretch of the gnomonic map); when cells are wider than 2 d, the cells that box touches are
the cells of its four corners (on a neighbouring face where the box crosses an edge).
`max_radius_rad` is the largest r for which that holds everywhere.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.spatial import cKDTree


@njit(cache=True)
def cell_of(x: float, y: float, z: float, grid: int) -> int:
    """Cell index of the direction (x, y, z) (any length > 0)."""
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax >= ay and ax >= az:
        face, u, v = (0 if x > 0 else 1), y / ax, z / ax
    elif ay >= az:
        face, u, v = (2 if y > 0 else 3), x / ay, z / ay
    else:
        face, u, v = (4 if z > 0 else 5), x / az, y / az
    i = min(int((u + 1.0) * 0.5 * grid), grid - 1)
    j = min(int((v + 1.0) * 0.5 * grid), grid - 1)
    return (face * grid + i) * grid + j


@njit(cache=True)
def cells_near(x: float, y: float, z: float, radius: float, grid: int, out: np.ndarray) -> int:
    """
    Cells that may hold stars within `radius` [rad] of the unit vector (x, y, z).

    Written to out[:count] (out has room for 4); returns count.
    """
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax >= ay and ax >= az:
        axis, major, u, v = 0, x, y / ax, z / ax
    elif ay >= az:
        axis, major, u, v = 1, y, x / ay, z / ay
    else:
        axis, major, u, v = 2, z, x / az, y / az
    d = 1.05 * radius * (1.0 + u * u + v * v) + 1e-12
    sign = 1.0 if major > 0 else -1.0
    count = 0
    for du in (-d, d):
        for dv in (-d, d):
            uu, vv = u + du, v + dv
            if axis == 0:
                c = cell_of(sign, uu, vv, grid)
            elif axis == 1:
                c = cell_of(uu, sign, vv, grid)
            else:
                c = cell_of(uu, vv, sign, grid)
            seen = False
            for q in range(count):
                if out[q] == c:
                    seen = True
            if not seen:
                out[count] = c
                count += 1
    return count


@dataclass(frozen=True)
class SkyGrid:
    """
    grid: cells per face edge.

    cell_start: (6 G^2 + 1,) offsets into star_of_cell (star indices sorted by cell);
    cell_density: (6 G^2,) catalog stars per steradian within `density_radius_rad` of each
    cell's centre [1/sr]; max_radius_rad: largest cone radius the 4-corner lookup covers
    exactly [rad].
    """

    grid: int
    cell_start: np.ndarray
    star_of_cell: np.ndarray
    cell_density: np.ndarray
    max_radius_rad: float

    @staticmethod
    def build(vectors: np.ndarray, grid: int = 32, density_radius_rad: float = math.radians(8.0)) -> "SkyGrid":
        cells = cells_of(np.ascontiguousarray(vectors, dtype=float), grid)
        order = np.argsort(cells, kind="stable")
        counts = np.bincount(cells, minlength=6 * grid * grid)
        cell_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        centres = cell_centres(grid)
        chord = 2.0 * math.sin(0.5 * density_radius_rad)
        near = cKDTree(vectors).query_ball_point(centres, chord, return_length=True)
        cap = 2.0 * math.pi * (1.0 - math.cos(density_radius_rad))
        # Cells are 2/G wide in (u, v); the box half-width d is at most 3.15 r (u = v = 1).
        return SkyGrid(grid, cell_start, order.astype(np.int64), np.asarray(near, float) / cap,
                       0.9 / (grid * 3.15))


@njit(cache=True)
def cells_of(vectors: np.ndarray, grid: int) -> np.ndarray:
    """Cell index (cell_of) of each of the (N, 3) direction `vectors`."""
    out = np.empty(vectors.shape[0], np.int64)
    for i in range(vectors.shape[0]):
        out[i] = cell_of(vectors[i, 0], vectors[i, 1], vectors[i, 2], grid)
    return out


def cell_centres(grid: int) -> np.ndarray:
    """Return unit vectors at the centre of every cell, in cell-index order."""
    centre = (np.arange(grid) + 0.5) / grid * 2.0 - 1.0
    u, v = np.meshgrid(centre, centre, indexing="ij")
    u, v, one = u.ravel(), v.ravel(), np.ones(grid * grid)
    faces = [np.stack([one, u, v], 1), np.stack([-one, u, v], 1), np.stack([u, one, v], 1),
             np.stack([u, -one, v], 1), np.stack([u, v, one], 1), np.stack([u, v, -one], 1)]
    out = np.concatenate(faces)
    return out / np.linalg.norm(out, axis=1, keepdims=True)
