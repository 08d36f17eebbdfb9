# SPDX-License-Identifier: Apache-2.0
"""
Camera self-calibration from identified stars: one camera fitted jointly with each frame's attitude.

Given, for one or several frames, the matched stars (spot pixel positions with their
covariances and the catalog unit vectors in ICRS), `calibrate_camera` fits the focal length
(fx and fy scaled together: the aspect ratio is kept), the radial distortion k1, k2 and the
principal point cx, cy of a `CameraModel`, together with every frame's attitude, by weighted
least squares on the pixel residuals (damped_least_squares.py; a soft-L1 loss first so a
wrong match cannot drag the fit, then a plain least-squares pass over the inliers for the
covariance). Tangential distortion p1, p2 and k3 are kept as given.

What is fitted is decided by the stars (`CalibrationConfig.max_corner_sigma_px`): the
parameter groups are nested, f ⊂ f + k1 ⊂ f + k1 + k2 ⊂ f + k1 + k2 + (cx, cy), and the largest
model is kept in which every fitted parameter is constrained: the 1-sigma uncertainty of f, k1
and k2 moves the image corner by at most max_corner_sigma_px pixels (f: r·σf, k1: f·r³·σk1,
k2: f·r⁵·σk2; r = tangent of the corner's angle off the boresight: the corner is where an
unconstrained distortion does harm), and the principal point's 1-sigma is at most
max_principal_point_sigma_px on each axis. Stars only near the centre cannot fix
k1 or k2, and one frame rarely fixes the principal point apart from the attitude: they are
then left at their given values and listed in `CameraCalibration.not_fitted`.

Frames: attitudes are rotations sensor (`star_tracker_optical`: +Z boresight, +X right, +Y
down) -> ICRS. Units: pixels [px], angles [rad], distortion coefficients dimensionless.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .attitude import rotation_vector_to_matrix, skew
from .calibration_kernel import PARAMETER_CODES, frame_rows
from .camera import CameraModel
from .damped_least_squares import damped_least_squares

# Nested models, smallest first: each group's parameter names (CameraCalibration.sigma keys).
PARAMETER_GROUPS = (("f",), ("k1",), ("k2",), ("cx", "cy"))
GROUP_NAMES = ("f", "k1", "k2", "principal_point")


@dataclass(frozen=True)
class CalibrationFrame:
    """
    One frame's matched stars.

    X, y (N,) spot positions [px]; cov (N, 2, 2) their covariance [px²]; stars (N, 3)
    catalog unit vectors in ICRS; rotation (3, 3) a first attitude sensor -> ICRS (the
    identification's).
    """

    x: np.ndarray
    y: np.ndarray
    cov: np.ndarray
    stars: np.ndarray
    rotation: np.ndarray

    def __post_init__(self) -> None:
        n = np.asarray(self.x).shape[0]
        shapes = {"x": (n,), "y": (n,), "cov": (n, 2, 2), "stars": (n, 3), "rotation": (3, 3)}
        for name, shape in shapes.items():
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != shape or not np.all(np.isfinite(value)):
                raise ValueError(f"calibration frame: {name} must be finite with shape {shape}, got {value.shape}")
            object.__setattr__(self, name, value)

    @property
    def size(self) -> int:
        return int(self.x.size)

    @staticmethod
    def from_identification(spots, identification) -> "CalibrationFrame":
        """Return the matched stars of a solved Identification of `spots` (unknown covariances: 1 px²)."""
        index = np.asarray(identification.spot_index)
        cov = np.asarray(spots.cov, dtype=float)[index] if spots.cov is not None else np.tile(np.eye(2),
                                                                                              (index.size, 1, 1))
        cov = np.where(np.isfinite(cov), cov, np.eye(2))
        return CalibrationFrame(spots.x[index], spots.y[index], cov, identification.star_vectors,
                                identification.attitude.rotation)


@dataclass(frozen=True)
class CalibrationConfig:
    """
    fit: the parameter groups that may be fitted, of GROUP_NAMES ("f" always is).

    max_corner_sigma_px, max_principal_point_sigma_px: the rule deciding which are (module
    docstring) [px]; sigma_floor_px: added in quadrature to every spot's 1-sigma (optics,
    JPEG, catalog) [px]; robust_scale: soft-L1 transition of the first pass [whitened
    sigmas]; outlier_sigma: a star whose whitened residual exceeds this many RMS is left out
    of the final pass [-]; min_stars_per_group: fewest stars (all frames) per fitted
    parameter.
    """

    fit: tuple[str, ...] = GROUP_NAMES
    max_corner_sigma_px: float = 2.0
    max_principal_point_sigma_px: float = 3.0
    sigma_floor_px: float = 0.3
    robust_scale: float = 3.0
    outlier_sigma: float = 5.0
    min_stars_per_group: int = 4

    def __post_init__(self) -> None:
        unknown = sorted(set(self.fit) - set(GROUP_NAMES))
        if unknown:
            raise ValueError(f"unknown calibration parameter group(s) {unknown}; expected some of {GROUP_NAMES}")
        for name in ("max_corner_sigma_px", "max_principal_point_sigma_px", "robust_scale", "outlier_sigma"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}={getattr(self, name)} must be > 0")
        if not self.sigma_floor_px >= 0:
            raise ValueError(f"sigma_floor_px={self.sigma_floor_px} must be >= 0")


@dataclass(frozen=True)
class CameraCalibration:
    """
    Result of calibrate_camera.

    camera: the fitted CameraModel; fitted: fitted parameter names of ("f", "k1", "k2", "cx",
    "cy") (f = fx, with fy scaled alike); not_fitted: the candidate groups the stars did not
    constrain (GROUP_NAMES); value, sigma: each fitted parameter's value and 1-sigma (f, cx, cy
    [px]; k1, k2 [-]); covariance: (P, P) in the order of `fitted` (f, cx, cy [px], k [-]);
    corner_sigma_px: each fitted parameter's 1-sigma effect at the image corner [px];
    rotations: each frame's fitted attitude sensor -> ICRS; inliers: each frame's mask of the
    stars kept; frame_rms_px: each frame's inlier residual RMS [px] (per axis); residual_rms_px:
    the same over all frames; stars: inliers over all frames; limits: the rule's limits it was
    decided by (max_corner_sigma_px, max_principal_point_sigma_px [px]).
    """

    camera: CameraModel
    fitted: tuple[str, ...]
    not_fitted: tuple[str, ...]
    value: dict
    sigma: dict
    covariance: np.ndarray
    corner_sigma_px: dict
    rotations: tuple
    inliers: tuple
    frame_rms_px: tuple
    residual_rms_px: float
    stars: int
    limits: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        """Plain values (JSON): fitted/not fitted names, values and 1-sigma, residuals."""
        return {"fitted": list(self.fitted), "not_fitted": list(self.not_fitted),
                "value": {k: float(v) for k, v in self.value.items()},
                "sigma": {k: float(v) for k, v in self.sigma.items()},
                "corner_sigma_px": {k: float(v) for k, v in self.corner_sigma_px.items()},
                "residual_rms_px": float(self.residual_rms_px), "stars": int(self.stars),
                "frame_rms_px": [float(r) for r in self.frame_rms_px],
                "frame_stars": [int(np.count_nonzero(m)) for m in self.inliers],
                **{k: float(v) for k, v in self.limits.items()}}


def corner_radius(camera: CameraModel) -> float:
    """Tangent of the angle between the boresight and the farthest image corner [-]."""
    return math.tan(camera.half_diagonal_fov_rad)


def calibrate_camera(frames, camera: CameraModel, config: CalibrationConfig = CalibrationConfig()) -> CameraCalibration:
    """
    Fit `camera` and each frame's attitude to the matched stars of `frames` (CalibrationFrame).

    `camera` gives the starting values (f, cx, cy, k1, k2; p1, p2, k3 kept); one frame or
    several. Keeps the largest nested model the stars constrain (module docstring). Raises
    ValueError with too few stars for even the focal length.
    """
    frames = list(frames)
    if not frames:
        raise ValueError("calibrate_camera needs at least one frame")
    total = sum(frame.size for frame in frames)
    if any(frame.size < 3 for frame in frames):
        raise ValueError(f"every frame needs >= 3 matched stars (got {[f.size for f in frames]})")
    groups = [0] + [i for i, name in enumerate(GROUP_NAMES) if i and name in config.fit]
    allowed = [g for g in groups if (groups.index(g) + 1) * config.min_stars_per_group <= total]
    radius = corner_radius(camera)
    for size in range(len(allowed), 0, -1):  # the largest model first; f alone is kept whatever its sigma
        names = tuple(n for g in allowed[:size] for n in PARAMETER_GROUPS[g])
        best = _fit(frames, camera, names, config, radius)
        if constrained(best, config):
            break
    not_fitted = tuple(GROUP_NAMES[g] for g in groups if not set(PARAMETER_GROUPS[g]) <= set(best.fitted))
    limits = {"max_corner_sigma_px": config.max_corner_sigma_px,
              "max_principal_point_sigma_px": config.max_principal_point_sigma_px}
    return replace(best, not_fitted=not_fitted, limits=limits)


def constrained(calibration: CameraCalibration, config: CalibrationConfig) -> bool:
    """Whether every fitted parameter passes the rule of the module docstring."""
    limits = {"cx": config.max_principal_point_sigma_px, "cy": config.max_principal_point_sigma_px}
    return all(calibration.sigma[n] <= limits[n] if n in limits
               else calibration.corner_sigma_px[n] <= config.max_corner_sigma_px for n in calibration.fitted)


def _camera_with(camera: CameraModel, names: tuple[str, ...], params: np.ndarray) -> CameraModel:
    """Return the camera with the fitted parameters: f as a log scale of fx (fy alike), cx, cy offsets [px], k1, k2."""
    values = dict(zip(names, params))
    scale = math.exp(values.get("f", 0.0))
    k1, k2, p1, p2, k3 = camera.distortion
    return CameraModel(camera.width, camera.height, camera.fx * scale, camera.fy * scale,
                       camera.cx + values.get("cx", 0.0), camera.cy + values.get("cy", 0.0),
                       (values.get("k1", k1), values.get("k2", k2), p1, p2, k3))


def _whitening(frames, sigma_floor_px: float) -> np.ndarray:
    """(N, 2, 2) matrices W with W d ~ N(0, I) for a pixel residual d of each star (all frames)."""
    cov = np.concatenate([frame.cov for frame in frames]) + sigma_floor_px ** 2 * np.eye(2)
    lower = np.linalg.cholesky(np.linalg.inv(cov))  # inv(cov) = L L^T  ->  |L^T d|² = d^T inv(cov) d
    return np.transpose(lower, (0, 2, 1))


def _fit(frames, camera: CameraModel, names: tuple[str, ...], config: CalibrationConfig,
         radius: float) -> CameraCalibration:
    """
    Fit one model: the camera parameters `names` and every frame's rotation.

    The rotation is a rotation vector applied to the frame's starting attitude; plain least
    squares, then soft-L1, then plain least squares over the inliers; covariance = (JᵀJ)⁻¹
    scaled by the inliers' reduced χ². radius: corner_radius [-].
    """
    count = len(frames)
    start = dict(zip(("f", "cx", "cy", "k1", "k2"), (0.0, 0.0, 0.0, camera.distortion[0], camera.distortion[1])))
    x0 = np.concatenate([np.zeros(3 * count), [start[n] for n in names]])
    whiten = _whitening(frames, config.sigma_floor_px)
    measured = np.concatenate([np.stack([frame.x, frame.y], axis=-1) for frame in frames])
    sizes = np.array([frame.size for frame in frames])
    bounds = np.concatenate([[0], np.cumsum(sizes)])

    whitened = _whitened_model(frames, camera, names, whiten, measured, bounds)
    # Plain least squares first: from the start it reaches the minimum's neighbourhood in a few
    # steps, where the robust pass then needs only a few more.
    plain = damped_least_squares(whitened, x0)
    robust = damped_least_squares(whitened, plain.x, robust_scale=config.robust_scale)
    norms = np.linalg.norm(robust.fun.reshape(-1, 2), axis=1)
    # Robust spread of the whitened residuals (the median norm of a 2-D unit normal is sqrt(2 ln 2)),
    # at least the stated one: noise-free or overestimated covariances must not make the cut tighter.
    spread = max(float(np.median(norms)) / math.sqrt(2.0 * math.log(2.0)), 1.0)
    keep = (norms <= config.outlier_sigma * spread).astype(float)
    if keep.all():
        final = plain  # every star an inlier: the final pass's problem is the plain fit's, solved already
    else:
        final = damped_least_squares(whitened, robust.x, rows=np.repeat(keep, 2))
    inlier_count = int(keep.sum())
    dof = max(2 * inlier_count - final.x.size, 1)
    reduced_chi2 = float(np.sum(final.fun ** 2)) / dof
    block = _camera_covariance(final.jac, count) * max(reduced_chi2, 1e-12)
    fitted_camera = _camera_with(camera, names, final.x[3 * count:])
    # f is fitted as a log scale: its covariance rows/columns scale by f.
    jacobian = np.diag([fitted_camera.fx if n == "f" else 1.0 for n in names])
    covariance = jacobian @ block @ jacobian
    sigma = {n: math.sqrt(max(covariance[i, i], 0.0)) if np.isfinite(covariance[i, i]) else float("inf")
             for i, n in enumerate(names)}
    value = {"f": fitted_camera.fx, "cx": fitted_camera.cx, "cy": fitted_camera.cy,
             "k1": fitted_camera.distortion[0], "k2": fitted_camera.distortion[1]}
    value = {n: value[n] for n in names}
    f = fitted_camera.fx
    effect = {"f": radius, "k1": f * radius ** 3, "k2": f * radius ** 5, "cx": 1.0, "cy": 1.0}  # d corner / d param
    corner = {n: sigma[n] * effect[n] for n in names}
    residual_px = _pixel_residuals(frames, fitted_camera, final.x, count)
    inliers, frame_rms = [], []
    for k in range(count):
        mask = keep[bounds[k]:bounds[k + 1]] > 0
        inliers.append(mask)
        r = residual_px[bounds[k]:bounds[k + 1]][mask]
        frame_rms.append(math.sqrt(float(np.mean(r ** 2))) if r.size else float("nan"))
    all_inliers = residual_px[keep > 0]
    rotations = tuple(frame.rotation @ rotation_vector_to_matrix(final.x[3 * k:3 * k + 3])
                      for k, frame in enumerate(frames))
    return CameraCalibration(fitted_camera, names, (), value, sigma, covariance, corner, rotations, tuple(inliers),
                             tuple(frame_rms), math.sqrt(float(np.mean(all_inliers ** 2))) if all_inliers.size
                             else float("nan"), inlier_count)


def _camera_covariance(jac, count: int) -> np.ndarray:
    """
    Camera block of (JᵀJ)⁻¹ for a Jacobian of `count` frames' rotations (3 columns each) then the camera's.

    The rotations are eliminated frame by frame (Schur complement: each frame's rotation couples
    only with itself and the camera), so neither the dense Jacobian nor the full inverse is formed
    (thousands of frames: gigabytes and most of the fit's time). Singular: inf.
    """
    normal = jac.T @ jac
    rotations = 3 * count
    if hasattr(normal, "tocsr"):
        normal = normal.tocsr()
        coupling = normal[:rotations, rotations:].toarray()
        camera_block = normal[rotations:, rotations:].toarray()
        diagonal = normal[:rotations, :rotations].tocoo()
        blocks = np.zeros((count, 3, 3))
        same = diagonal.row // 3 == diagonal.col // 3
        blocks[diagonal.row[same] // 3, diagonal.row[same] % 3, diagonal.col[same] % 3] = diagonal.data[same]
    else:
        coupling, camera_block = normal[:rotations, rotations:], normal[rotations:, rotations:]
        blocks = np.stack([normal[3 * k:3 * k + 3, 3 * k:3 * k + 3] for k in range(count)])
    size = camera_block.shape[0]
    try:
        coupling = coupling.reshape(count, 3, size)
        schur = camera_block - np.einsum("kip,kiq->pq", coupling, np.linalg.solve(blocks, coupling))
        return np.linalg.inv(schur)
    except np.linalg.LinAlgError:
        return np.full((size, size), np.inf)


def _whitened_model(frames, camera: CameraModel, names: tuple[str, ...], whiten: np.ndarray, measured: np.ndarray,
                    bounds: np.ndarray):
    """
    Return f(params) -> (whitened residuals (2N,), their Jacobian (2N, P)); the last evaluation is kept.

    params: every frame's rotation vector (3 each, applied after its starting attitude), then the
    camera parameters `names` (_camera_with). The Jacobian is analytic: dense for one frame,
    scipy.sparse CSR for several (a frame's rotation moves only its own stars).
    """
    from scipy import sparse

    count = len(frames)
    size = int(bounds[-1])
    last: dict = {}

    codes = np.array([PARAMETER_CODES[name] for name in names], np.int64)
    stars = [np.ascontiguousarray(frame.stars, np.float64) for frame in frames]
    whiten = np.ascontiguousarray(whiten, np.float64)
    measured = np.ascontiguousarray(measured, np.float64)

    def evaluate(params):
        key = params.tobytes()
        if last.get("key") == key:
            return last["value"]
        # The camera of _camera_with, as plain numbers (a CameraModel per call cost as much as the
        # arithmetic on ~100 stars).
        values = dict(zip(names, params[3 * count:].tolist()))
        scale = math.exp(values.get("f", 0.0))
        intrinsics = np.array([camera.fx * scale, camera.fy * scale, camera.cx + values.get("cx", 0.0),
                               camera.cy + values.get("cy", 0.0)])
        k1, k2, p1, p2, k3 = camera.distortion
        distortion = np.array([values.get("k1", k1), values.get("k2", k2), p1, p2, k3], np.float64)
        residual = np.empty((size, 2))
        rotation_block = np.empty((size, 2, 3))
        camera_block = np.empty((size, 2, len(names)))
        for k, frame in enumerate(frames):
            theta = params[3 * k:3 * k + 3]
            rows = slice(int(bounds[k]), int(bounds[k + 1]))
            frame_rows(stars[k], frame.rotation @ rotation_vector_to_matrix(theta), _right_jacobian(theta), intrinsics,
                       distortion, codes, whiten[rows], measured[rows], residual[rows], rotation_block[rows],
                       camera_block[rows])
        residual = residual.ravel()
        camera_block = camera_block.reshape(2 * size, len(names))
        if count == 1:
            jac = np.concatenate([rotation_block.reshape(2 * size, 3), camera_block], axis=1)
        else:
            frame_of_row = np.repeat(np.repeat(np.arange(count), np.diff(bounds)), 2)
            row = np.arange(2 * size)
            rows = np.concatenate([np.repeat(row, 3), np.repeat(row, len(names))])
            cols = np.concatenate([(3 * frame_of_row[:, None] + np.arange(3)).ravel(),
                                   np.tile(3 * count + np.arange(len(names)), 2 * size)])
            data = np.concatenate([rotation_block.reshape(-1), camera_block.reshape(-1)])
            jac = sparse.csr_matrix((data, (rows, cols)), shape=(2 * size, 3 * count + len(names)))
        last.update(key=key, value=(residual, jac))
        return residual, jac

    return evaluate


def _right_jacobian(theta: np.ndarray) -> np.ndarray:
    """(3, 3) J_r with Exp(theta + d) = Exp(theta) Exp(J_r d) to first order (theta a rotation vector [rad])."""
    angle = float(np.linalg.norm(theta))
    k = skew(theta)
    if angle < 1e-8:
        return np.eye(3) - 0.5 * k
    return (np.eye(3) - (1.0 - math.cos(angle)) / angle ** 2 * k
            + (angle - math.sin(angle)) / angle ** 3 * (k @ k))


def _pixel_residuals(frames, camera: CameraModel, params: np.ndarray, count: int) -> np.ndarray:
    """(N, 2) predicted - measured [px] of every star of every frame at the fitted parameters."""
    out = []
    for k, frame in enumerate(frames):
        rotation = frame.rotation @ rotation_vector_to_matrix(params[3 * k:3 * k + 3])
        u, v, _ = camera.project(frame.stars @ rotation)
        out.append(np.stack([u - frame.x, v - frame.y], axis=-1))
    return np.concatenate(out)
