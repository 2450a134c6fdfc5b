"""sim.sitl_autopilot's pure parts, no firmware needed: where the camera points from a mount report, the scene's
frame, the flight-mode names."""
from __future__ import annotations

import math

import pytest

from sim.autopilot import euler_to_quaternion
from sim.sitl_autopilot import SceneOrigin, camera_direction, firmware_kind, mode_name
from sim.vehicle_model import ARDUCOPTER_MODES, mount_angles_in_body, px4_custom_mode


def test_servo_mount_report_is_turned_by_the_vehicle_attitude():
    """ArduCopter SITL, 4.8 m/s pitched 18.8 deg nose down: the servo mount reported -26.2 deg; the camera looks
    -45 deg (what the sim renders), not -26.2."""
    q = euler_to_quaternion(0.0, math.radians(-26.2), 0.0)
    pitch, yaw = camera_direction(q, 44, (0.0, math.radians(-18.8), 1.0), mount_in_body_frame=True)
    assert math.degrees(pitch) == pytest.approx(-45.0, abs=1e-6) and yaw == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("vehicle", [(0.2, -0.1, 2.0), (-0.1, 0.25, -0.5)])
def test_camera_direction_inverts_the_mock_servo_mount(vehicle):
    q = euler_to_quaternion(*mount_angles_in_body(vehicle, -0.7, 0.6))
    pitch, yaw = camera_direction(q, 44, vehicle, mount_in_body_frame=True)
    assert pitch == pytest.approx(-0.7, abs=1e-9) and yaw == pytest.approx(0.6, abs=1e-9)


def test_earth_framed_report_keeps_pitch_and_makes_yaw_vehicle_relative():
    """PX4 (flags 12): pitch as reported whatever the vehicle's lean; a yaw flagged YAW_IN_EARTH_FRAME (64) is
    turned relative to the nose."""
    q = euler_to_quaternion(0.0, -0.5, 0.3)
    assert camera_direction(q, 12, (0.2, -0.3, 1.0), mount_in_body_frame=False) == pytest.approx((-0.5, 0.3))
    assert camera_direction(q, 12 | 64, (0.2, -0.3, 1.0), mount_in_body_frame=False) == pytest.approx((-0.5, 0.3 - 1.0))


def test_scene_origin_turns_the_heading_into_scene_north():
    origin = SceneOrigin(10.0, -5.0, math.radians(90.0))  # hovering at (10, -5), nose east
    assert origin.to_scene(10.0, 25.0) == pytest.approx((30.0, 0.0))  # 30 m east of it: 30 m ahead
    assert origin.to_scene(0.0, -5.0) == pytest.approx((0.0, 10.0))  # 10 m south: 10 m to its right


def test_mode_names_and_firmware_kinds():
    assert mode_name("ardupilot", ARDUCOPTER_MODES["GUIDED"]) == "GUIDED"
    assert mode_name("px4", px4_custom_mode(6)) == "OFFBOARD"
    assert mode_name("px4", px4_custom_mode(4, 3)) == "HOLD"
    assert mode_name("ardupilot", 99) == "MODE 99"
    assert firmware_kind("ardupilot") == "arducopter" and firmware_kind("px4") == "px4"
    with pytest.raises(ValueError, match="flavour"):
        firmware_kind("betaflight")


def test_a_relative_firmware_folder_is_taken_from_the_working_directory(tmp_path, monkeypatch):
    """JSAR_SITL_ROOT=../shared/sitl (as one types it at the repository root) stays right when the firmware is
    started in a folder of its own."""
    from sim.firmware import sitl_root

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("JSAR_SITL_ROOT", "firmware/sitl")
    assert sitl_root() == tmp_path / "firmware" / "sitl"
    assert sitl_root().is_absolute()
