# SPDX-License-Identifier: Apache-2.0
"""
A lost-in-space result against its scene's truth: the stars it named, its error and its covariance.

Wrong: any matched star that is not the star behind its spot (a false object named a catalog
star included), a wrong attitude, or an error outside 5 sigma of the covariance the solution
states (NEES beyond chi^2_3 at the two-sided 5-sigma probability): a right answer is near
the truth by its own account. A wrong attitude: the boresight more than `wrong_arcsec` from
the truth, or the error outside 10 sigma (what no consistent estimate gives; between 5 and
10 sigma is the covariance's tail: 5.7e-7 of consistent solves lie beyond 5 sigma). Of these,
a false identification in the verification's sense (the bound
IdentifyConfig.false_positive_bound states) is a wrong attitude or a wrong guide star; a wrong
star of the deep re-match alone (deep_match.py: faint stars named after the attitude is
accepted) and an error between 5 and 10 sigma with every star right are counted apart.
"""
from __future__ import annotations

import math

import numpy as np
import pyarrow as pa
from scipy.stats import chi2, norm

ARCSEC = math.pi / (180.0 * 3600.0)
# NEES beyond chi^2_3 at the two-sided 5-sigma probability (31.8): a consistent covariance
# exceeds it 5.7e-7 of the time, ~1.7 times in 3 million solves; at 10 sigma (a chance of
# 1.5e-23) no consistent estimate does.
OUTSIDE_5_SIGMA_CHANCE = 2.0 * float(norm.sf(5.0))
NEES_5_SIGMA = float(chi2.isf(OUTSIDE_5_SIGMA_CHANCE, 3))
NEES_10_SIGMA = float(chi2.isf(2.0 * norm.sf(10.0), 3))


SCORE_COLUMNS = (pa.field("wrong", pa.bool_()), pa.field("wrong_star", pa.bool_()),
                 pa.field("false_identification", pa.bool_()), pa.field("wrong_attitude", pa.bool_()),
                 pa.field("wrong_deep_star", pa.bool_()), pa.field("cross_arcsec", pa.float64()),
                 pa.field("roll_arcsec", pa.float64()), pa.field("nees", pa.float64()),
                 pa.field("outside_5_sigma", pa.bool_()))
UNSOLVED = {"wrong": False, "wrong_star": False, "false_identification": False, "wrong_attitude": False,
            "wrong_deep_star": False, "cross_arcsec": None, "roll_arcsec": None, "nees": None,
            "outside_5_sigma": False}


def score(result, hip_truth: np.ndarray, rotation_truth: np.ndarray, wrong_arcsec: float) -> dict:
    """
    Return the record fields of a solved Identification against the truth.

    hip_truth: the HIP id behind each input spot (0: a false object); rotation_truth: sensor ->
    ICRS. Fields: wrong, wrong_star, false_identification, wrong_attitude, wrong_deep_star,
    cross_arcsec (boresight error), roll_arcsec, nees, outside_5_sigma.
    """
    from ...models.attitude import matrix_to_rotation_vector

    named = np.asarray(result.hip, np.int64)
    mislabeled = named != np.asarray(hip_truth, np.int64)[np.asarray(result.spot_index, np.int64)]
    deep = np.asarray(result.deep, bool) if len(result.deep) == len(named) else np.zeros(len(named), bool)
    error = matrix_to_rotation_vector(rotation_truth.T @ result.attitude.rotation)  # sensor frame [rad]
    nees = float(error @ np.linalg.solve(result.attitude.covariance, error))
    cross = math.hypot(error[0], error[1])
    wrong_attitude = bool(cross > wrong_arcsec * ARCSEC or nees > NEES_10_SIGMA)
    outside = bool(nees > NEES_5_SIGMA)
    wrong_guide = bool(np.any(mislabeled & ~deep))
    return {"wrong": bool(wrong_attitude or outside or mislabeled.any()), "wrong_star": bool(mislabeled.any()),
            "false_identification": wrong_attitude or wrong_guide, "wrong_attitude": wrong_attitude,
            "wrong_deep_star": bool(np.any(mislabeled & deep)), "cross_arcsec": cross / ARCSEC,
            "roll_arcsec": abs(error[2]) / ARCSEC, "nees": nees, "outside_5_sigma": outside}


def campaign_identify_config():
    """
    Return the identifier's configuration in a campaign: the defaults, the time budget on the CPU clock.

    A campaign's outcome must not depend on what else the machine runs: on the default wall
    clock a loaded host times out solves that an idle one finishes.
    """
    from ...identify import IdentifyConfig

    return IdentifyConfig(budget_clock="cpu")
