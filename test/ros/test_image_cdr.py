# SPDX-License-Identifier: Apache-2.0
"""The centroider's in-place reading of serialized Images, against rclpy's own (de)serialization."""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Image

from star_tracker.centroid import extract_spots
from star_tracker.ros import convert
from star_tracker.ros.image_cdr import parse_image


def image_message(rng, encoding, width, height, pad, frame_id, sec, nanosec, bigendian=0):
    item = 2 if encoding in ("mono16", "16UC1") else 1
    msg = Image()
    msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id = sec, nanosec, frame_id
    msg.height, msg.width, msg.encoding, msg.is_bigendian = height, width, encoding, bigendian
    msg.step = width * item + pad
    msg.data = rng.integers(0, 256, size=msg.step * height, dtype=np.uint8).tobytes()
    return msg


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "16UC1", "8UC1"])
def test_every_field_and_pixel_reads_as_rclpy_deserializes_it(encoding):
    rng = np.random.default_rng(7)
    layouts = ((1, 1, 0, "", 0), (7, 3, 1, "a", 0), (1024, 4, 0, "star_tracker_optical", 1),
               (13, 5, 3, "é/ünïcode", 0), (640, 480, 0, "x" * 3, 0))
    for width, height, pad, frame_id, bigendian in layouts:
        msg = image_message(rng, encoding, width, height, pad, frame_id, int(rng.integers(-2**31, 2**31)),
                            int(rng.integers(0, 10**9)), bigendian)
        raw = serialize_message(msg)
        parsed, reference = parse_image(raw), deserialize_message(raw, Image)
        assert (parsed.header.stamp.sec, parsed.header.stamp.nanosec, parsed.header.frame_id) == \
            (reference.header.stamp.sec, reference.header.stamp.nanosec, reference.header.frame_id)
        assert (parsed.height, parsed.width, parsed.encoding, parsed.is_bigendian, parsed.step) == \
            (reference.height, reference.width, reference.encoding, reference.is_bigendian, reference.step)
        assert bytes(parsed.data) == bytes(reference.data)
        view = convert.image_to_array(parsed)
        copied = convert.image_to_array(reference)
        assert np.array_equal(view, copied) and view.dtype == copied.dtype
        if pad == 0 and not bigendian:  # rows without padding in native order: a view, no copy
            assert not view.flags.owndata and not view.flags.writeable


def test_truncated_or_foreign_bytes_are_a_value_error():
    rng = np.random.default_rng(3)
    raw = serialize_message(image_message(rng, "mono16", 16, 8, 0, "frame", 5, 6))
    for cut in (0, 3, 4, 9, 20, 40, len(raw) - 1):
        with pytest.raises(ValueError):
            convert.image_to_array(parse_image(raw[:cut]))
    with pytest.raises(ValueError, match="representation"):
        parse_image(b"\x00\x09" + raw[2:])
    for _ in range(500):  # random bytes: a ValueError or an image, never another exception
        junk = b"\x00\x01\x00\x00" + rng.integers(0, 256, size=int(rng.integers(0, 64)), dtype=np.uint8).tobytes()
        try:
            convert.image_to_array(parse_image(junk))
        except ValueError:
            pass


def test_a_read_only_view_is_measured_as_a_copy_is(catalog, nominal_camera):
    from star_tracker.models.attitude import radec_roll_to_matrix
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import StarFieldRenderer, frame_seed
    from star_tracker.sim.sensor import SensorModel

    renderer = StarFieldRenderer(nominal_camera, SensorModel(), catalog, magnitude_limit=7.0)
    image = renderer.render(ConstantRateMotion(radec_roll_to_matrix(1.0, 0.3, 0.0), np.zeros(3)), 0.05,
                            frame_seed(1, 0)).image
    view = convert.image_to_array(parse_image(serialize_message(convert.array_to_image(image, 1, "f"))))
    assert not view.flags.writeable
    a, b = extract_spots(view), extract_spots(image.copy())
    assert len(a) > 20 and np.array_equal(a.x, b.x) and np.array_equal(a.flux, b.flux)
