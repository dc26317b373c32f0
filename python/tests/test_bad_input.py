"""Each bad input raises the exception a Python user expects, with the command line's message,
and the tracker goes on where the fault was the input's alone."""

import numpy as np
import pytest

import vitracker as vt
from conftest import BOARD_START


@pytest.fixture()
def tracker(board_model):
    camera = vt.Camera(320, 240, 300.0, 300.0, 159.5, 119.5)
    with vt.Tracker(vt.Model(board_model), camera, start_pose=BOARD_START, rate_hz=30.0) as t:
        yield t


def test_a_wrong_dtype_is_a_value_error(tracker):
    with pytest.raises(ValueError, match="dtype is float32, expected uint8"):
        tracker.push_frame(0.0, np.zeros((240, 320), np.float32))


def test_a_wrong_size_or_shape_is_a_value_error(tracker):
    with pytest.raises(ValueError, match="the image is 321x240 pixels, the camera's are 320x240"):
        tracker.push_frame(0.0, np.zeros((240, 321), np.uint8))
    with pytest.raises(ValueError, match=r"shape is \[240, 320, 4\]"):
        tracker.push_frame(0.0, np.zeros((240, 320, 4), np.uint8))
    with pytest.raises(ValueError, match="expected a numpy array"):
        tracker.push_frame(0.0, [[0] * 320] * 240)
    # The tracker took none of them, and goes on.
    tracker.push_frame(0.0, np.zeros((240, 320), np.uint8))


def test_time_going_backwards_is_a_value_error_and_the_tracker_goes_on(tracker):
    frame = np.zeros((240, 320), np.uint8)
    tracker.push_frame(1.0, frame)
    with pytest.raises(ValueError, match="is not after the previous one"):
        tracker.push_frame(0.5, frame)
    with pytest.raises(ValueError, match="not a finite number of seconds"):
        tracker.push_frame(float("nan"), frame)
    tracker.push_frame(1.1, frame)
    assert [r.index for r in tracker.poll() if r.skipped is None][-1] >= 1


def test_a_non_rigid_start_pose_is_a_value_error(board_model):
    camera = vt.Camera(320, 240, 300.0, 300.0, 159.5, 119.5)
    model = vt.Model(board_model)
    scaled = BOARD_START.copy()
    scaled[:3, :3] *= 1.1
    with pytest.raises(ValueError, match="not orthonormal"):
        vt.Tracker(model, camera, start_pose=scaled, rate_hz=30.0)
    mirrored = BOARD_START.copy()
    mirrored[0, 0] = -1.0
    with pytest.raises(ValueError, match="not \\+1 \\(a reflection\\)"):
        vt.Tracker(model, camera, start_pose=mirrored, rate_hz=30.0)
    with pytest.raises(ValueError, match="4×4"):
        vt.Tracker(model, camera, start_pose=np.eye(3), rate_hz=30.0)


def test_missing_files_are_file_not_found_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.obj: file not found"):
        vt.Model(tmp_path / "nothing.obj")
    with pytest.raises(FileNotFoundError, match="camera.json"):
        vt.Camera.from_json(tmp_path / "camera.json")
    with pytest.raises(FileNotFoundError, match="pose.json"):
        vt.read_pose(tmp_path / "pose.json")


def test_bad_settings_are_value_errors(board_model):
    camera = vt.Camera(320, 240, 300.0, 300.0, 159.5, 119.5)
    model = vt.Model(board_model)
    with pytest.raises(ValueError, match="frame rate"):
        vt.Tracker(model, camera, start_pose=BOARD_START)
    with pytest.raises(ValueError, match="link: "):
        vt.Tracker(model, camera, start_pose=BOARD_START, rate_hz=30.0, link="usb")
    with pytest.raises(ValueError, match="principal point|invalid"):
        vt.Camera(320, 240, 300.0, 300.0, 500.0, 119.5)
    with pytest.raises(ValueError, match="radtan"):
        vt.Camera(320, 240, 300.0, 300.0, 159.5, 119.5, "radtan", [0.1])
    with pytest.raises(ValueError, match="mount on the IMU"):
        vt.Tracker(model, camera, start_pose=BOARD_START, imu=vt.Imu(200.0), rate_hz=20.0)
    with pytest.raises(ValueError, match="four noise densities"):
        vt.Imu(200.0, gyroscope_noise_density=1e-3)


def test_imu_samples_are_checked(board_model):
    camera = vt.Camera(320, 240, 300.0, 300.0, 159.5, 119.5)
    imu = vt.Imu(100.0, t_bs=np.eye(4))
    with vt.Tracker(vt.Model(board_model), camera, BOARD_START, imu, rate_hz=25.0) as tracker:
        tracker.push_imu(0.00, [0, 0, 0], [0, 0, 9.81])
        with pytest.raises(ValueError, match="gyro: expected 3 numbers, got 2"):
            tracker.push_imu(0.01, [0, 0], [0, 0, 9.81])
        with pytest.raises(ValueError, match="accel: .* is not finite"):
            tracker.push_imu(0.01, [0, 0, 0], [0, 0, float("inf")])
        with pytest.raises(ValueError, match="IMU sample at .* is not after the previous one"):
            tracker.push_imu(0.00, [0, 0, 0], [0, 0, 9.81])
        tracker.push_imu(0.01, [0, 0, 0], [0, 0, 9.81])


def test_a_finished_tracker_takes_nothing_more(board_model):
    camera = vt.Camera(320, 240, 300.0, 300.0, 159.5, 119.5)
    tracker = vt.Tracker(vt.Model(board_model), camera, BOARD_START, rate_hz=30.0)
    tracker.finish()
    with pytest.raises(vt.TrackerError, match="finished"):
        tracker.push_frame(0.0, np.zeros((240, 320), np.uint8))


def test_the_core_behind_a_byte_link(board_model):
    """`link=` puts the core elsewhere: here the simulated board on a pty pair, as a serial
    board would be reached; the frames go through as in-process."""
    camera = vt.Camera(320, 240, 300.0, 300.0, 159.5, 119.5)
    with vt.Tracker(vt.Model(board_model), camera, BOARD_START, rate_hz=30.0,
                    link="sim") as tracker:
        for i in range(3):
            tracker.push_frame(i / 30.0, np.zeros((240, 320), np.uint8))
        assert len(tracker.poll()) == 3
        assert tracker.pose is not None
