# SPDX-License-Identifier: Apache-2.0
"""
The attitude_fusion node's parameters without ROS: specs, shipped YAML, mounting convention, refusals.

A bad value is refused with the parameter's name and the reason (the node's configure fails on
it and the node stays unconfigured: test_attitude_fusion_nodes.py shows that over DDS).
"""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from star_tracker.models.attitude import ARCSEC
from star_tracker.parameter_spec import dotted_names
from star_tracker.ros import parameter_yaml
from star_tracker.ros.attitude_fusion_parameters import (ATTITUDE_FUSION_PARAMETERS, DEFAULT_HEADS, fusion_parameters,
                                                         fusion_settings, mounting_matrix)

DEFAULTS = {spec.name: list(spec.default) if isinstance(spec.default, tuple) else spec.default
            for spec in ATTITUDE_FUSION_PARAMETERS}


def values(**changes) -> dict:
    """Return the default values with `changes` (dots in names written as __)."""
    return {**DEFAULTS, **{name.replace("__", "."): value for name, value in changes.items()}}


def test_the_shipped_yaml_holds_every_fusion_parameter_with_its_default_and_type():
    shipped = dotted_names(yaml.safe_load(parameter_yaml.SHIPPED.read_text())["/**/attitude_fusion"]["ros__parameters"])
    assert set(shipped) == set(DEFAULTS)
    for name, default in DEFAULTS.items():
        assert shipped[name] == default and type(shipped[name]) is type(default), name
        if isinstance(default, list):
            assert len({type(v) for v in default}) == 1, name
    for spec in ATTITUDE_FUSION_PARAMETERS:
        assert spec.description and spec.problem(spec.default) is None and not spec.dynamic, spec.name


def test_default_heads_are_90_degrees_apart_along_body_z_and_x():
    settings = fusion_settings(values())
    assert settings.heads == DEFAULT_HEADS == ("head1", "head2")
    boresight = {head: m.T @ [0.0, 0.0, 1.0] for head, m in settings.mountings.items()}  # M^T z: in the body frame
    assert np.allclose(boresight["head1"], [0, 0, 1]) and np.allclose(boresight["head2"], [1, 0, 0])
    # head2's image x and y (its row and column directions) are body y and z.
    assert np.allclose(settings.mountings["head2"], [[0, 1, 0], [0, 0, 1], [1, 0, 0]])
    assert settings.alignment.heads == ("head1", "head2") and settings.alignment.initial_sigma_rad == 2.9e-4
    assert settings.fusion.stale_after_s == 0.3 and settings.rate_source == "heads"
    assert 59.5 * ARCSEC < settings.alignment.initial_sigma_rad < 60.5 * ARCSEC


def test_the_mounting_is_the_head_frames_orientation_in_the_body_frame():
    """Quaternion q (x, y, z, w) with R(q) v_head = v_body, the tf2 body -> head transform; M = R(q)^T."""
    half = np.sqrt(0.5)
    m = mounting_matrix("head3", [half, 0.0, 0.0, half])  # 90 deg about body x: head z (boresight) = body -y
    assert np.allclose(m.T @ [0.0, 0.0, 1.0], [0.0, -1.0, 0.0])
    assert np.allclose(m @ m.T, np.eye(3))


def test_more_heads_need_their_own_mountings_and_a_reference_among_them():
    heads = ["head1", "head2", "head3"]
    specs = {spec.name: spec for spec in fusion_parameters(heads)}
    assert specs["mounting.head3"].default == (0.0, 0.0, 0.0, 0.0)  # not set
    with pytest.raises(ValueError, match=r"mounting.head3 is not set"):
        fusion_settings(values(heads=heads, mounting__head3=[0.0, 0.0, 0.0, 0.0]))
    settings = fusion_settings(values(heads=heads, mounting__head3=[-0.5, -0.5, -0.5, 0.5],
                                      alignment__reference="head2"))
    assert np.allclose(settings.mountings["head3"].T @ [0.0, 0.0, 1.0], [0.0, 1.0, 0.0])  # along body +Y
    assert settings.alignment.heads == ("head2", "head1", "head3")  # the reference first
    assert settings.fusion.heads == tuple(heads)


def test_one_head_runs_without_the_alignment_filter():
    settings = fusion_settings(values(heads=["head1"]))
    assert settings.alignment is None and settings.fusion.heads == ("head1",)


@pytest.mark.parametrize("changes, message", [
    (dict(heads=None), "heads is empty"),  # `heads:=[]` reaches the node as no value
    (dict(heads=[]), "heads is empty"),
    (dict(heads=["head1", "2nd"]), r"heads \['2nd'\] are not names"),
    (dict(heads=["head1", "head1"]), "name a head twice"),
    (dict(mounting__head2=[0.5, 0.5, 0.5, 0.4]), r"mounting.head2=\[0.5, 0.5, 0.5, 0.4\] is not a unit quaternion"),
    (dict(mounting__head2=[0.7071, 0.0, 0.7071, 0.0]), "give at least 7 digits"),
    (dict(mounting__head2=[0.0, 0.0, 1.0]), "must be 4 finite values"),
    (dict(mounting__head1=[float("nan"), 0.0, 0.0, 1.0]), "must be 4 finite values"),
    (dict(alignment__reference="head9"), "alignment.reference='head9' is not one of heads"),
    (dict(fusion__stale_after_s=0.0), r"fusion.stale_after_s=0.0 must be in \(0, 3600\]"),
    (dict(alignment__gate_probability=1.0), r"alignment.gate_probability=1.0 must be in \(0, 1\)"),
    (dict(body_rate__source="gyro"), "body_rate.source='gyro' must be one of"),
    (dict(body_frame_id=""), "body_frame_id is empty"),
])
def test_bad_values_are_refused_with_the_parameter_and_the_reason(changes, message):
    with pytest.raises(ValueError, match=message):
        fusion_settings(values(**changes))
