# SPDX-License-Identifier: Apache-2.0
"""
`false-id`: lost-in-space trials on independent scenes, counting wrong identifications.

Each trial is a scene as the identification benchmark makes them (sim/scenes.py: a random
attitude uniform over the sphere, the catalog's stars projected through the camera with
position and magnitude noise, false stars among them) identified lost-in-space by the
default identifier (no prior, no tracking), and scored (scoring.py: wrong = a star named
wrongly, a boresight more than `wrong_arcsec` off, or an error outside 5 sigma of the stated
covariance); deep_matched and deep_wrong count each solve's deep re-match stars and the wrong
ones among them (`magnitude_limit` beyond the guide stars' puts deep-catalog stars in the
scenes). The summary gives the empirical false-identification rate with
its one-sided 95 % upper bound (Clopper-Pearson; 3/n with none wrong) beside the bound the
verification states (IdentifyConfig.false_positive_bound, and what each solve reported).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from ..bounds import rate_upper_bound
from ...parameter_spec import parameter
from ..kind import CampaignKind
from .lost_in_space import SceneOptions, SceneShared, prepare_scenes
from .scoring import NEES_5_SIGMA, OUTSIDE_5_SIGMA_CHANCE, SCORE_COLUMNS, UNSOLVED, score


@dataclass(frozen=True)
class FalseIdOptions(SceneOptions):
    """The scenes and the identifier of a false-id campaign (lost_in_space.SceneOptions), and the scenes' star limit."""

    magnitude_limit: float = parameter(0.0, "faintest star that makes a spot (0: the setup's; beyond the guide "
                                            "stars' 6.5 the scenes hold deep-catalog stars)", "Hp mag", 0.0, 12.0)

    def __post_init__(self) -> None:
        bad = self.problems()
        if bad:
            raise ValueError("false-id options: " + "; ".join(bad))


class FalseIdentification(CampaignKind):
    """Lost-in-space trials counting wrong identifications (module docstring)."""

    name = "false-id"
    description = "lost-in-space trials on random scenes with noise and false stars: the false-identification bound"
    options_type = FalseIdOptions
    default_trials = 3_000_000
    default_batch = 1000
    columns = (pa.field("solved", pa.bool_()), *SCORE_COLUMNS, pa.field("matched", pa.int32()),
               pa.field("real_spots", pa.int32()), pa.field("deep_matched", pa.int32()),
               pa.field("deep_wrong", pa.int32()), pa.field("stated_probability", pa.float64()),
               pa.field("identify_s", pa.float64()))

    def prepare(self, options: FalseIdOptions) -> SceneShared:
        return prepare_scenes(options, options.magnitude_limit or None)

    def trial(self, shared: SceneShared, options: FalseIdOptions, task: int, rng: np.random.Generator) -> dict:
        from ...sim.scenes import make_scene

        scene = make_scene(shared.setup, shared.catalog, rng, vectors=shared.vectors)
        started = time.perf_counter()
        result = shared.identifier.identify(scene.spots, shared.setup.camera)
        elapsed = time.perf_counter() - started
        record = {"solved": result.solved, **UNSOLVED,
                  "matched": int(result.hip.size) if result.solved else 0, "real_spots": scene.real_count,
                  "stated_probability": float(result.false_positive_probability) if result.solved else None,
                  "identify_s": elapsed}
        record["deep_matched"] = record["deep_wrong"] = 0
        if result.solved:
            record.update(score(result, scene.hip, scene.rotation, options.wrong_arcsec))
            deep = np.asarray(result.deep, bool)
            named = np.asarray(result.hip, np.int64) != scene.hip[np.asarray(result.spot_index, np.int64)]
            record["deep_matched"] = int(np.count_nonzero(deep))
            record["deep_wrong"] = int(np.count_nonzero(deep & named))
        return record

    def summarize(self, table: pa.Table, options: FalseIdOptions) -> dict:
        from ...identify import IdentifyConfig

        ok = np.asarray(table.column("error").to_pylist(), object) == ""
        solved = np.asarray(table.column("solved").fill_null(False), bool) & ok
        wrong = np.asarray(table.column("wrong").fill_null(False), bool) & ok
        trials = int(ok.sum())
        correct = int((solved & ~wrong).sum())
        stated = np.asarray(table.column("stated_probability").fill_null(np.nan), float)[solved]
        times = np.asarray(table.column("identify_s").fill_null(np.nan), float)[ok]
        right = solved & ~wrong
        cross = np.asarray(table.column("cross_arcsec").fill_null(np.nan), float)[right]
        roll = np.asarray(table.column("roll_arcsec").fill_null(np.nan), float)[right]
        nees = np.asarray(table.column("nees").fill_null(np.nan), float)[solved]
        return {
            "trials": trials, "correct": correct, "wrong": int(wrong.sum()), "unsolved": int(trials - solved.sum()),
            "failed_tasks": int((~ok).sum()),
            **{name: int(np.asarray(table.column(name).fill_null(False), bool)[ok].sum())
               for name in ("wrong_star", "wrong_attitude", "wrong_deep_star", "false_identification",
                            "outside_5_sigma")},
            "outside_5_sigma_expected": float(solved.sum() * OUTSIDE_5_SIGMA_CHANCE),
            "false_identification_upper_95": rate_upper_bound(
                int(np.asarray(table.column("false_identification").fill_null(False), bool)[ok].sum()), trials, 0.95)
            if trials else None,
            "deep_matched": int(np.asarray(table.column("deep_matched").fill_null(0), np.int64)[ok].sum())
            if "deep_matched" in table.column_names else None,
            "deep_wrong": int(np.asarray(table.column("deep_wrong").fill_null(0), np.int64)[ok].sum())
            if "deep_wrong" in table.column_names else None,
            "wrong_deep_star_rate": float(np.asarray(table.column("wrong_deep_star").fill_null(False), bool)[ok].mean())
            if trials else None,
            "wrong_rate": float(wrong.sum() / trials) if trials else None,
            "wrong_rate_upper_95": rate_upper_bound(int(wrong.sum()), trials, 0.95) if trials else None,
            "wrong_per_solved_upper_95": rate_upper_bound(int(wrong.sum()), int(solved.sum()), 0.95)
            if solved.any() else None,
            "availability": float(solved.sum() / trials) if trials else None,
            "stated_bound": IdentifyConfig().false_positive_bound,
            "stated_probability_median": float(np.median(stated)) if stated.size else None,
            "stated_probability_max": float(np.max(stated)) if stated.size else None,
            "cross_arcsec_rms": float(np.sqrt(np.mean(cross ** 2))) if cross.size else None,
            "roll_arcsec_rms": float(np.sqrt(np.mean(roll ** 2))) if roll.size else None,
            "nees_mean": float(np.mean(nees)) if nees.size else None,
            "nees_beyond_5_sigma": int(np.sum(nees > NEES_5_SIGMA)),
            "identify_ms_median": float(np.median(times) * 1e3) if times.size else None,
            "identify_ms_p99": float(np.quantile(times, 0.99) * 1e3) if times.size else None,
        }
