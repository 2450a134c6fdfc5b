"""gimbal.attitude_frame: a mount attitude reported against the vehicle's body (ArduPilot's servo mount) is read
in the earth frame with the vehicle's attitude; MAVLink's own definition (earth) is the default."""
from __future__ import annotations

import math

import pytest

from service.config import ConfigError, config_from_mapping
from service.control.geo import GimbalAttitude, gimbal_attitude_from_status, gimbal_in_earth_frame
from sim.autopilot import euler_to_quaternion
from sim.vehicle_model import mount_angles_in_body


def test_a_servo_mount_braking_vehicle_is_read_at_its_earth_pitch():
    """ArduCopter SITL flying 4.8 m/s pitched 18.8 degrees nose down reported its servo mount at -26.2 degrees
    while the camera was held at -45 degrees to the horizon: read as body-frame, that is -45."""
    report = GimbalAttitude(math.radians(-26.2), 0.0, False)
    earth = gimbal_in_earth_frame(report, 0.0, math.radians(-18.8), 0.3)
    assert math.degrees(earth.pitch) == pytest.approx(-45.0, abs=1e-6)
    assert earth.yaw == pytest.approx(0.0, abs=1e-9) and not earth.yaw_in_earth_frame


@pytest.mark.parametrize("vehicle", [(0.1, -0.2, 0.5), (-0.25, 0.15, -2.0), (0.0, 0.0, 3.0)])
@pytest.mark.parametrize("camera", [(-0.8, 0.4), (-0.2, -1.2), (-1.4, 2.5)])
def test_body_frame_report_of_any_lean_gives_back_the_camera_direction(vehicle, camera):
    """Round trip through the message: the mount angles a level camera needs on a leaning vehicle (the mock's
    ArduPilot flavour sends those), as a quaternion, read back as earth pitch and yaw relative to the nose."""
    q = euler_to_quaternion(*mount_angles_in_body(vehicle, *camera))
    read = gimbal_in_earth_frame(gimbal_attitude_from_status(tuple(q), 44), *vehicle)
    assert read.pitch == pytest.approx(camera[0], abs=1e-9)
    assert math.remainder(read.yaw - camera[1], math.tau) == pytest.approx(0.0, abs=1e-9)
    # read as earth-framed (the default), the same report points elsewhere where the vehicle leans
    naive = gimbal_attitude_from_status(tuple(q), 44)
    if max(abs(vehicle[0]), abs(vehicle[1])) > 0.1:
        assert max(abs(naive.pitch - camera[0]), abs(math.remainder(naive.yaw - camera[1], math.tau))) > 0.03


def test_attitude_frame_is_earth_by_default_and_a_bad_value_names_the_key():
    assert config_from_mapping({}).gimbal.attitude_frame == "earth"
    assert config_from_mapping({"gimbal": {"attitude_frame": "body"}}).gimbal.attitude_frame == "body"
    with pytest.raises(ConfigError, match="gimbal.attitude_frame"):
        config_from_mapping({"gimbal": {"attitude_frame": "vehicle"}})
