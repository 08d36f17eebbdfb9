# SPDX-License-Identifier: Apache-2.0
"""
The parameter specs (star_tracker/parameter_spec.py and the nodes' *_parameters.py), without ROS.

The shipped config/star_tracker.yaml is the generated one, its values read back with the specs'
types, the core configurations check their ranges from the same specs.
"""
from __future__ import annotations

import dataclasses

import pytest
import yaml

from star_tracker.centroid import CentroidConfig
from star_tracker.identify import DatabaseConfig, IdentifyConfig
from star_tracker.models.online_calibration import OnlineCalibrationConfig
from star_tracker.parameter_spec import (SPEC_KEY, ParameterSpec, dotted_names, field_specs, field_values,
                                         range_problems)
from star_tracker.ros import parameter_yaml
from star_tracker.ros.camera_simulator_parameters import (CAMERA_SIMULATOR_PARAMETERS, SENSOR_PARAMETERS,
                                                          SIMULATED_SENSOR, sensor_from)
from star_tracker.ros.centroider_parameters import CENTROIDER_PARAMETERS
from star_tracker.ros.identifier_parameters import IDENTIFIER_PARAMETERS
from star_tracker.sim.render import FalseObjectModel
from star_tracker.sim.sensor import SensorModel
from star_tracker.track.tracking import TrackingConfig

CONFIGS = (CentroidConfig, IdentifyConfig, DatabaseConfig, TrackingConfig, OnlineCalibrationConfig, SensorModel,
           FalseObjectModel)
NODES = {"camera_simulator": CAMERA_SIMULATOR_PARAMETERS, "centroider": CENTROIDER_PARAMETERS,
         "identifier": IDENTIFIER_PARAMETERS}


def test_the_shipped_yaml_is_the_generated_one():
    assert parameter_yaml.SHIPPED.read_text() == parameter_yaml.generate(), \
        "config/star_tracker.yaml differs from the specs: python -m star_tracker.ros.parameter_yaml --write"
    assert parameter_yaml.main(["--check"]) == 0


@pytest.mark.parametrize("node", sorted(NODES))
def test_the_yaml_holds_every_parameter_with_its_default_and_type(node):
    shipped = dotted_names(yaml.safe_load(parameter_yaml.SHIPPED.read_text())[f"/**/{node}"]["ros__parameters"])
    specs = {spec.name: spec for spec in NODES[node]}
    assert len(specs) == len(NODES[node]), "a parameter declared twice"
    assert set(shipped) == set(specs)
    for name, spec in specs.items():
        default = list(spec.default) if isinstance(spec.default, tuple) else spec.default
        assert shipped[name] == default and type(shipped[name]) is type(default), name
        if isinstance(default, list):  # a ROS array parameter has one element type
            assert len({type(v) for v in default}) <= 1, name


def test_every_spec_is_described_and_its_default_in_range():
    for specs in NODES.values():
        for spec in specs:
            assert spec.description and spec.problem(spec.default) is None, spec.name
            assert not (spec.choices and spec.has_range), spec.name


def test_known_defaults():
    """
    The decisions of issue 18.

    The centroider has the rate aid without the params file (the simulator's exposure);
    saturation_adu 0 = the image dtype's maximum, as `solve` has it.
    """
    centroider = {spec.name: spec for spec in CENTROIDER_PARAMETERS}
    assert centroider["exposure_time_s"].default == 0.1
    assert centroider["saturation_adu"].default == 0.0 == CentroidConfig().saturation_adu
    camera = {spec.name: spec for spec in CAMERA_SIMULATOR_PARAMETERS}
    assert camera["sensor.exposure_s"].default == centroider["exposure_time_s"].default


@pytest.mark.parametrize("config_class", CONFIGS, ids=lambda c: c.__name__)
def test_core_defaults_pass_their_own_checks(config_class):
    config = config_class()
    assert range_problems(config) == []
    for f in dataclasses.fields(config_class):
        spec = f.metadata.get(SPEC_KEY)
        if spec is not None:
            assert spec.default == f.default, f.name  # the metadata's default is the field's


@pytest.mark.parametrize("config_class, field, value, message", [
    (CentroidConfig, "detection_sigma", 0.5, "detection_sigma=0.5 must be in [1, 100]"),
    (CentroidConfig, "method", "best", "method='best' must be one of"),
    (CentroidConfig, "min_snr", float("nan"), "min_snr=nan must be in [0, 1e+06]"),
    (IdentifyConfig, "angle_tolerance_floor_rad", 0.01, "angle_tolerance_floor_rad=0.01 must be in [0, 0.01)"),
    (IdentifyConfig, "max_time_s", 0.0, "max_time_s=0.0 must be in [0.001, 60]"),
    (TrackingConfig, "min_stars", 11, "min_stars=11 must be in [2, 10]"),
    (OnlineCalibrationConfig, "apply_corner_sigma_px", 0.0, "apply_corner_sigma_px=0.0 must be in (0, 10]"),
    (SensorModel, "exposure_s", -1.0, "exposure_s=-1.0 must be in [1e-06, 10]"),
    (DatabaseConfig, "magnitude_limit", 13.0, "magnitude_limit=13.0 must be in [-2, 12]"),
    (FalseObjectModel, "planets_per_frame", 101, "planets_per_frame=101 must be in [0, 100]"),
])
def test_core_range_checks_come_from_the_specs_and_name_the_field(config_class, field, value, message):
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("(", r"\(").replace(")", r"\)")
                       .replace("+", r"\+").replace(".", r"\.")):
        config_class(**{field: value})


def test_cross_field_checks_stay():
    with pytest.raises(ValueError, match=r"min_area \(50\) <= max_area \(10\)"):
        CentroidConfig(min_area=50, max_area=10)
    with pytest.raises(ValueError, match="needs psf_sigma_px > 0"):
        CentroidConfig(psf_sigma_px=0.0)


def test_field_specs_rename_and_take_other_defaults():
    specs = {spec.field: spec for spec in SENSOR_PARAMETERS}
    assert specs["optical_transmission"].name == "optics.transmission"
    assert specs["exposure_s"].name == "sensor.exposure_s" and specs["exposure_s"].unit == "s"
    assert specs["dsnu_fraction"].default == SIMULATED_SENSOR.dsnu_fraction != SensorModel().dsnu_fraction
    assert specs["exposure_s"].dynamic and not specs["pixel_pitch_m"].dynamic
    values = {spec.name: spec.default for spec in SENSOR_PARAMETERS}
    assert sensor_from(values) == SIMULATED_SENSOR
    assert field_values(SENSOR_PARAMETERS, {"sky.stray_light_gradient_e_per_px2_s": [1.0, 2.0]}) == \
        {"stray_light_gradient_e_per_px2_s": (1.0, 2.0)}
    tracking = field_specs(TrackingConfig, prefix="tracking.", only=("gate_sigma",))
    assert [(s.name, s.field) for s in tracking] == [("tracking.gate_sigma", "gate_sigma")]


def test_the_camera_files_of_the_cli_use_the_simulated_sensor():
    """`star-tracker render` without --camera renders the camera_simulator's camera."""
    from star_tracker.commands.camera_files import default_camera_file

    assert default_camera_file().sensor == SIMULATED_SENSOR


def test_spec_problem_and_description():
    spec = ParameterSpec("x", 1.0, "a length", "m", 0.0, 2.0, low_open=True, dynamic=True)
    assert spec.problem(0.0) == "x=0.0 must be in (0, 2]"
    assert spec.problem(2.0) is None and spec.problem([1.0, 3.0]) == "x=[1.0, 3.0] must be in (0, 2]"
    assert spec.full_description() == "a length [m]"
    with pytest.raises(ValueError, match="default of x=3.0"):
        ParameterSpec("x", 3.0, "a length", "m", 0.0, 2.0)
    with pytest.raises(ValueError, match="both ends"):
        ParameterSpec("x", 1.0, "a length", "m", 0.0)


def test_yaml_values_read_back_with_their_type():
    for value in (1.0, 2e-05, 1e10, 0.08726646259971647, 3, True, "auto", [0.0, 1.5], [-1]):
        back = yaml.safe_load(f"v: {parameter_yaml.yaml_value(value)}")["v"]
        assert back == value and type(back) is type(value), value
