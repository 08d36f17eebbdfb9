# SPDX-License-Identifier: Apache-2.0
"""
Campaign kinds, their scoring and the bound on a counted rate, without a Dask cluster of processes.

A trial that raises is a record with its seed and error; the presets are scored against their
scenes' truth; the sky-coverage grid points the boresight at each HEALPix pixel's centre.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pytest
from scipy.stats import binom

from star_tracker.campaign import CampaignKind, CampaignSpec, run_campaign
from star_tracker.campaign.bounds import rate_upper_bound
from star_tracker.campaign.engine import run_batch
from star_tracker.campaign.presets import KINDS
from star_tracker.campaign.results import ResultStore
from star_tracker.parameter_spec import parameter


@dataclass(frozen=True)
class _Options:
    fail_every: int = parameter(4, "trial t raises when t % fail_every == 3", "", 1, 100)


class _Flaky(CampaignKind):
    """A kind whose every fourth trial raises: the engine records it and goes on."""

    name = "flaky"
    description = "test kind"
    options_type = _Options
    columns = (pa.field("value", pa.float64()),)
    default_trials = 10
    default_batch = 5

    def prepare(self, options):
        return None

    def trial(self, shared, options, task, rng):
        if task % options.fail_every == 3:
            raise RuntimeError(f"trial {task} broke")
        return {"value": float(rng.uniform())}

    def summarize(self, table, options):
        return {"trials": table.num_rows}


@pytest.mark.parametrize("events, trials", [(0, 3_000_000), (0, 1000), (3, 1000), (40, 200)])
def test_the_rate_bound_is_the_binomial_one_sided_95_percent_bound(events, trials):
    bound = rate_upper_bound(events, trials)
    assert binom.cdf(events, trials, bound) == pytest.approx(0.05, rel=1e-6)  # the rate at which k or fewer is 5 %
    if events == 0:
        assert bound == pytest.approx(1.0 - 0.05 ** (1.0 / trials), rel=1e-9)
    assert rate_upper_bound(0, 3_000_000) < 1e-6 < rate_upper_bound(0, 2_990_000)


def test_a_trial_that_raises_is_recorded_with_its_seed_and_the_campaign_goes_on(tmp_path):
    kind, spec = _Flaky(), CampaignSpec("flaky", trials=10, seed=5, batch=5)
    table = pa.concat_tables([run_batch(kind, spec, b).table for b in range(spec.batches)])
    errors = dict(zip(table.column("task").to_pylist(), table.column("error").to_pylist()))
    assert [t for t, e in errors.items() if e] == [3, 7]
    assert errors[3].startswith("RuntimeError: trial 3 broke") and table.column("seed").to_pylist() == [5] * 10
    values = table.column("value").to_pylist()
    assert values[3] is None and values[0] == np.random.default_rng(np.random.SeedSequence([5, 0])).uniform()
    # The same through the engine, on an in-process Dask cluster.
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        run = run_campaign(kind, spec, tmp_path, client=client)
    assert run.batches_run == 2 and run.trials_run == 10
    stored = ResultStore(tmp_path, spec, kind.schema()).read()
    assert stored.to_pydict() == table.to_pydict()


def test_a_kind_without_its_declarations_is_refused_when_defined():
    with pytest.raises(TypeError, match="lacks"):
        class _Incomplete(CampaignKind):  # noqa: F841 - defining it is the test
            def prepare(self, options):
                return None

            def trial(self, shared, options, task, rng):
                return {}

            def summarize(self, table, options):
                return {}


def test_the_command_lists_every_preset():
    from star_tracker.commands.characterize import PRESETS

    assert set(PRESETS) == set(KINDS)


@pytest.mark.slow
def test_sky_coverage_points_each_boresight_at_its_pixel_and_scores_against_the_truth(database, tmp_path):
    kind = KINDS["sky-coverage"]()
    spec = CampaignSpec("sky-coverage", trials=24, seed=3, batch=24, options={"nside": 1, "rolls": 2})
    table = run_batch(kind, spec, 0).table
    assert not any(table.column("error").to_pylist())
    ra, dec = np.asarray(table.column("ra_rad")), np.asarray(table.column("dec_rad"))
    centres = np.unique(np.column_stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)]), axis=0)
    assert len(centres) == 12 and np.allclose(centres.sum(axis=0), 0.0, atol=1e-12)  # 12 equal-area pixels
    # nside 1's pixel centres: dec +-41.8 deg (4 each) and 0 (4), as HEALPix defines them.
    assert sorted(np.round(np.degrees(np.unique(np.round(dec, 9))), 2)) == [-41.81, 0.0, 41.81]
    solved = np.asarray(table.column("solved"))
    assert solved.sum() >= 22 and not np.asarray(table.column("wrong")).any()
    cross = np.asarray(table.column("cross_arcsec"))[solved]
    assert np.all(cross < 20.0)  # the identified boresight is the pixel's centre, by the scene's truth
    summary = kind.summarize(table, kind.options(spec.options))
    assert summary["trials"] == 24 and summary["pixels_tried"] == 12
    assert summary["pixels_failing"] == len(summary["failing"]) == sum(
        1 for p in range(12) if not all(np.asarray(table.column("solved"))[np.asarray(table.column("pixel")) == p]))
    files = kind.report(table, summary, kind.options(spec.options), tmp_path)
    assert all(f.exists() and f.stat().st_size > 0 for f in files)


@pytest.mark.slow
def test_false_id_scores_a_wrongly_named_star_and_an_overconfident_attitude(database):
    """The scoring itself: a correct result perturbed into each kind of wrong is counted wrong."""
    from dataclasses import replace

    from star_tracker.campaign.presets.scoring import NEES_5_SIGMA, score
    from star_tracker.models.attitude import rotation_vector_to_matrix

    kind = KINDS["false-id"]()
    options = kind.options({})
    shared = kind.prepare(options)
    from star_tracker.sim.scenes import make_scene

    scene = make_scene(shared.setup, shared.catalog, np.random.default_rng(8))
    result = shared.identifier.identify(scene.spots, shared.setup.camera)
    assert result.solved
    right = score(result, scene.hip, scene.rotation, 60.0)
    assert not right["wrong"] and right["nees"] < NEES_5_SIGMA
    renamed = replace(result, hip=np.where(np.arange(result.hip.size) == 0, result.hip[1], result.hip))
    named_wrong = score(renamed, scene.hip, scene.rotation, 60.0)
    assert named_wrong["wrong_star"] and named_wrong["wrong"] and not named_wrong["wrong_attitude"]
    assert named_wrong["false_identification"] != bool(result.deep[0])  # a guide star named wrongly is one
    turned = scene.rotation @ rotation_vector_to_matrix([0.0, 0.0, 20.0 * math.sqrt(result.attitude.covariance[2, 2])])
    moved = score(result, scene.hip, turned, 60.0)
    assert moved["wrong"] and moved["false_identification"] and not moved["wrong_star"] and moved["nees"] > NEES_5_SIGMA


def test_the_nested_split_recovers_known_error_terms():
    """Errors built as bias + pointing + offset + frame terms of known sigmas come back as those terms."""
    from star_tracker.campaign.presets.accuracy import error_terms

    rng = np.random.default_rng(4)
    pointings, offsets, repeats = 400, 6, 8
    fov, pixel, temporal, bias = 0.30, 0.20, 0.50, 0.05
    p = np.repeat(np.arange(pointings), offsets * repeats)
    o = np.tile(np.repeat(np.arange(offsets), repeats), pointings)
    error = (bias + rng.normal(0, fov, pointings)[p] + rng.normal(0, pixel, (pointings, offsets))[p, o]
             + rng.normal(0, temporal, p.size))
    terms = error_terms(error, p, o)
    assert terms["temporal_noise"] == pytest.approx(temporal, rel=0.03)
    assert terms["pixel_spatial"] == pytest.approx(pixel, rel=0.1)
    assert terms["fov_spatial"] == pytest.approx(fov, rel=0.1)
    assert terms["bias"] == pytest.approx(bias, abs=0.05)
    # No pixel or FOV term in the data: they come out (near) zero, never negative.
    flat = error_terms(rng.normal(0, temporal, p.size), p, o)
    assert flat["pixel_spatial"] < 0.05 and flat["fov_spatial"] < 0.05


@pytest.mark.slow
def test_accuracy_trials_nest_their_attitudes_and_measure_rendered_frames(database):
    from star_tracker.campaign.presets.accuracy import trial_attitude

    kind = KINDS["accuracy"]()
    spec = CampaignSpec("accuracy", trials=8, seed=1, batch=8,
                        options={"pointings": 2, "offsets": 2, "repeats": 2})
    options = kind.options(spec.options)
    attitudes = [trial_attitude(options, t) for t in range(8)]
    assert [a[:3] for a in attitudes] == [(p, o, r) for p in range(2) for o in range(2) for r in range(2)]
    assert np.allclose(attitudes[0][3], attitudes[1][3]) and not np.allclose(attitudes[0][3], attitudes[2][3])
    pixel = math.radians(15.0) / 1024
    turn = np.arccos(np.clip((np.trace(attitudes[0][3].T @ attitudes[2][3]) - 1) / 2, -1, 1))
    assert 0 < turn <= math.sqrt(2) * 0.5 * pixel * 1.01  # a sub-pixel offset of the same pointing
    table = run_batch(kind, spec, 0).table
    assert not any(table.column("error").to_pylist()) and all(table.column("solved").to_pylist())
    assert not any(table.column("wrong").to_pylist())
    cross = np.hypot(np.asarray(table.column("error_x_arcsec")), np.asarray(table.column("error_y_arcsec")))
    assert np.all(cross < 2.0)  # the rendered truth, to the accuracy the datasheet states (~0.2")
    summary = kind.summarize(table, options)
    assert set(summary["axes"]) == {"x", "y", "roll"} and summary["axes"]["x"]["temporal_noise"] > 0


def test_tracking_options_parse_their_grid_and_refuse_a_bad_one():
    kind = KINDS["tracking"]()
    options = kind.options({"rates_deg_s": "1, 2.5", "accelerations_deg_s2": 2, "runs": 3})
    assert options.rates == (1.0, 2.5) and options.accelerations == (2.0,) and options.trials == 6
    for bad in ({"rates_deg_s": "1,fast"}, {"accelerations_deg_s2": "0,1"}, {"runs": 0}):
        with pytest.raises(ValueError):
            kind.options(bad)


@pytest.mark.slow
def test_tracking_sequences_follow_a_slew_against_the_rendered_truth(database):
    kind = KINDS["tracking"]()
    spec = CampaignSpec("tracking", trials=2, seed=4, batch=1,
                        options={"rates_deg_s": "1", "accelerations_deg_s2": "2", "runs": 2, "frames": 12})
    table = pa.concat_tables([run_batch(kind, spec, b).table for b in range(2)])
    assert not any(table.column("error").to_pylist())
    rows = table.to_pylist()
    assert all(r["first_solved"] == 0 and r["wrong"] == 0 and r["lost"] == 0 for r in rows)
    assert all(r["right"] == 12 and r["tracked"] >= 10 for r in rows)  # tracked after the first solve
    assert all(r["cross_arcsec_max"] < 10.0 for r in rows)
    # 0.5 s at rest, then 2 deg/s^2 to 1 deg/s: the exposures of frames 5-9 (0.5-1.0 s) see the rate change.
    assert all(r["accelerating_frames"] == 5 and r["steady_frames"] == 7 for r in rows)
    summary = kind.summarize(table, kind.options(spec.options))
    assert summary["envelope_rate_deg_s_by_acceleration"] == {"2": 1.0} and summary["cases"][0]["right_share"] == 1.0
    phases = summary["phases"]
    assert phases["accelerating"]["frames"] == 10 and phases["steady"]["frames"] == 14
    assert sum(p["overconfident"] for p in phases.values()) == sum(r["overconfident"] for r in rows)


def test_robustness_options_lay_out_the_sweeps_and_refuse_an_unknown_one():
    from star_tracker.campaign.presets.robustness import STRESS_LEVELS

    kind = KINDS["robustness"]()
    options = kind.options({"sweeps": "cosmic_rays, temperature", "frames": 3})
    assert options.cases == tuple(("cosmic_rays", v) for v in STRESS_LEVELS["cosmic_rays"]) + tuple(
        ("temperature", v) for v in STRESS_LEVELS["temperature"])
    assert options.trials == 3 * len(options.cases)
    for bad in ({"sweeps": "cosmic_rays,sunburn"}, {"sweeps": ""}, {"frames": 0}):
        with pytest.raises(ValueError):
            kind.options(bad)


@pytest.mark.slow
def test_robustness_frames_carry_their_stress_and_are_scored_against_the_truth(database):
    """The strongest false-object and stray-light levels are in the rendered frames; every level solves right."""
    from star_tracker.campaign.presets.robustness import STRESS_LEVELS
    from star_tracker.sim.render import KIND_PLANET

    kind = KINDS["robustness"]()
    spec = CampaignSpec("robustness", trials=10, seed=5, batch=10,
                        options={"sweeps": "false_objects,stray_light", "frames": 1})
    options = kind.options(spec.options)
    shared = kind.prepare(options)
    most = kind._renderer(shared, "false_objects", STRESS_LEVELS["false_objects"][-1])
    frame = most.render(_at_rest(), 0.0, 7)
    assert int(np.sum(frame.truth.kind == KIND_PLANET)) == STRESS_LEVELS["false_objects"][-1]
    bright = kind._renderer(shared, "stray_light", STRESS_LEVELS["stray_light"][-1])
    image = bright.render(_at_rest(), 0.0, 7).image.astype(float)
    exposure_s, level = shared.sensor.exposure_s, STRESS_LEVELS["stray_light"][-1]
    centre = np.median(image[480:544, 480:544]) - shared.sensor.bias_adu
    assert centre == pytest.approx(level * exposure_s, rel=0.1)  # plus dark current: 2 e-
    rise = (np.median(image[480:544, -64:]) - np.median(image[480:544, :64])) / 2.0 / centre
    assert rise == pytest.approx(0.5 * (512 - 32) / math.hypot(512, 512), rel=0.15)
    table = run_batch(kind, spec, 0).table
    assert not any(table.column("error").to_pylist()) and table.num_rows == 10
    summary = kind.summarize(table, options)
    assert summary["wrong"] == 0 and [c["level"] for c in summary["sweeps"]["false_objects"]] == list(
        STRESS_LEVELS["false_objects"])
    assert summary["sweeps"]["stray_light"][0]["availability"] == 1.0  # the default sky


def _at_rest():
    from star_tracker.models.attitude import quaternion_to_matrix
    from star_tracker.sim.motion import ConstantRateMotion

    return ConstantRateMotion(quaternion_to_matrix(np.array([0.1, -0.4, 0.3, 0.85])), np.zeros(3))


def test_the_tracking_envelope_ends_at_the_slowest_case_that_failed():
    """A case that held above one that failed does not extend the envelope (2 deg/s failed: 1 deg/s at 4 deg/s^2)."""
    kind = KINDS["tracking"]()
    options = kind.options({"rates_deg_s": "1,2,3", "accelerations_deg_s2": "1,4", "runs": 1})
    rows = []
    for acceleration in (1.0, 4.0):
        for rate in (1.0, 2.0, 3.0):
            failed = acceleration == 4.0 and rate == 2.0
            rows.append({"task": len(rows), "seed": 0, "error": "", "rate_deg_s": rate,
                         "acceleration_deg_s2": acceleration, "frames": 10, "first_solved": 0,
                         "right": 9 if failed else 10, "wrong": 1 if failed else 0, "lost": 0, "overconfident": 0,
                         "tracked": 9, "cross_arcsec_rms": 1.0, "cross_arcsec_max": 2.0, "nees_mean": 3.0,
                         "first_loss_rate_deg_s": None, "reached_rate_deg_s": rate, "frame_s": 0.01})
    table = pa.Table.from_pylist(rows, schema=kind.schema())
    summary = kind.summarize(table, options)
    assert summary["envelope_rate_deg_s_by_acceleration"] == {"1": 3.0, "4": 1.0}


def test_a_streak_spot_is_its_star_within_its_own_covariance_and_no_further():
    """4 px along a streak whose along-track sigma is 1.5 px: its star (5 sigma holds); across it: no star."""
    from types import SimpleNamespace

    from star_tracker.campaign.presets.accuracy import truth_hip
    from star_tracker.sim.render import KIND_STAR

    truth = SimpleNamespace(kind=np.full(3, KIND_STAR), x=np.array([100.0, 300.0, 500.0]),
                            y=np.array([100.0, 300.0, 500.0]), hip=np.array([11, 22, 33]))
    along = np.diag([1.5 ** 2, 0.1 ** 2])  # a streak along x
    spots = SimpleNamespace(x=np.array([104.0, 300.0, 500.2]), y=np.array([100.0, 304.0, 500.1]),
                            cov=np.array([along, along, along]))
    result = SimpleNamespace(spot_index=np.array([0, 1, 2]), hip=np.array([11, 22, 33]))
    hip = truth_hip(truth, _Sized(spots, 3), result)
    assert hip.tolist() == [11, 0, 33]  # 4 px along: its star; 4 px across (40 sigma): none; 0.2 px: its star


class _Sized:
    """A namespace with a length, as Spots has."""

    def __init__(self, inner, n):
        self.__dict__.update(vars(inner))
        self._n = n

    def __len__(self):
        return self._n
