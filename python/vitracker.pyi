"""Markerless model-based tracking: numpy frames (and IMU samples) in, the camera's pose out.

A textured 3D model of an object or scene and a calibrated camera give the camera's pose in the
model's frame at every frame, fused in an extended Kalman filter (the paper's fusion core, run
in-process by default or on a board over a serial link). Without an IMU the filter predicts
with constant velocity; with one (`Imu`), at the IMU's rate.

    import cv2, vitracker as vt
    camera = vt.Camera.from_json("camera.json")
    model = vt.Model("model/cube.obj")
    tracker = vt.Tracker(model, camera, start_pose="frame0_pose.json", rate_hz=30)
    capture = cv2.VideoCapture("video.mp4")
    while (frame := capture.read()[1]) is not None:
        tracker.push_frame(capture.get(cv2.CAP_PROP_POS_MSEC) / 1e3, frame)
        for report in tracker.poll():
            print(report.index, report.tracked, report.pose)

Errors: `ValueError` for a wrong dtype, shape, size, order or setting; `FileNotFoundError`
for a missing file; `TrackerError` for the rest. Each carries the message the command line
(`host-vision`) prints for the same fault.

Conventions: metres, seconds, radians; the model's frame is the world frame; the camera frame
is OpenCV's (x right, y down, z forward); pixel (0, 0) is the top-left pixel's centre.
"""

import os
from typing import Literal, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

__version__: str

PathLike = Union[str, "os.PathLike[str]"]
ArrayLike = Union[npt.ArrayLike, Sequence[float]]

class TrackerError(Exception):
    """The tracker could not start, stopped, or lost its core: everything that is not a wrong
    argument (`ValueError`) or a missing file (`FileNotFoundError`)."""

class Camera:
    """A calibrated camera: image size, intrinsics and lens distortion; the mount on an IMU
    and the frame rate where its calibration file gives them."""

    def __init__(
        self,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        distortion_model: Literal["none", "radtan", "equidistant"] = "none",
        distortion: Sequence[float] = (),
        rate_hz: Optional[float] = None,
    ) -> None:
        """A camera of `width × height` pixels, focal lengths `fx`, `fy` and principal point
        `cx`, `cy` [px]. `distortion`: k1, k2, p1, p2[, k3] for "radtan" (OpenCV's
        plumb_bob), k1..k4 for "equidistant" (fisheye). Raises ValueError for impossible
        numbers (a principal point outside the image, a focal length ≤ 0)."""
    @staticmethod
    def from_json(path: PathLike) -> "Camera":
        """A `camera.json` (pinhole, no distortion), as `host-vision --camera` reads it."""
    @staticmethod
    def from_euroc(path: PathLike) -> "Camera":
        """A EuRoC/ASL `sensor.yaml`: intrinsics, distortion, `T_BS` and `rate_hz`."""
    @staticmethod
    def from_kalibr(path: PathLike, index: int = 0) -> "Camera":
        """Camera `index` of a Kalibr camchain YAML; its `T_cam_imu` gives the mount."""
    @property
    def width(self) -> int:
        """Image width [px]."""
    @property
    def height(self) -> int:
        """Image height [px]."""
    @property
    def k(self) -> npt.NDArray[np.float64]:
        """The 3×3 intrinsic matrix."""
    @property
    def t_bs(self) -> Optional[npt.NDArray[np.float64]]:
        """The camera's pose in the IMU's frame (4×4, camera → IMU), or None."""
    @property
    def rate_hz(self) -> Optional[float]:
        """The frame rate its file gives, or None."""
    def project(self, pose: "Pose", points: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Pixels `(N, 2)` of model points `(N, 3)` [m] seen from `pose`, with the lens's
        distortion; NaN for points behind the camera."""

class Model:
    """A triangle model in metres: OBJ (with its MTL and textures) or glTF."""

    def __init__(self, path: PathLike) -> None:
        """Loads `path` (`.obj`, `.gltf`, `.glb`). FileNotFoundError for a missing model or
        texture, ValueError for a file that cannot be used."""
    @property
    def triangles(self) -> int:
        """Its triangles."""
    @property
    def textured(self) -> bool:
        """Whether a material has a texture. An untextured model is tracked by its contour
        and needs a start pose."""
    def edges(self, angle_deg: float = 30.0) -> npt.NDArray[np.float64]:
        """Its edges as a person would draw them, `(N, 2, 3)` segments [m]: creases sharper
        than `angle_deg` and open boundaries. For drawing: `camera.project(pose, e.reshape(-1, 3))`."""

class Pose:
    """A camera pose in the model's frame."""

    def __init__(self, cMo: ArrayLike) -> None:
        """The pose of a rigid 4×4 `cMo` (model → camera: `X_c = R X_o + t`, metres).
        ValueError where it is not rigid (scaled, sheared, a reflection, a last row other
        than 0 0 0 1)."""
    @property
    def matrix(self) -> npt.NDArray[np.float64]:
        """The 4×4 `cMo` (model → camera)."""
    @property
    def position(self) -> npt.NDArray[np.float64]:
        """The camera's centre in the model's frame [m] (TUM's tx ty tz)."""
    @property
    def quaternion(self) -> npt.NDArray[np.float64]:
        """The camera's orientation in the model's frame, camera → model, as (x, y, z, w)
        (TUM's qx qy qz qw)."""
    @property
    def t(self) -> Optional[float]:
        """Its time [s from the tracker's first frame or sample]; None for a given pose."""
    @property
    def covariance(self) -> Optional[npt.NDArray[np.float64]]:
        """The core's 6×6 covariance of `[position, θ]` [m², rad²]: θ the orientation's error
        as a rotation vector in the model's frame (docs/VISION.md eq. T6); None for a given
        pose. Its calibration on the corpus is in the README (`host-vision corpus`)."""
    def tum(self) -> str:
        """The TUM line `t tx ty tz qx qy qz qw` (evo reads a file of them)."""

def read_pose(path: PathLike) -> Pose:
    """A start pose file: JSON with a 4×4 `cMo`, or one TUM line (as `host-vision track
    --start-pose` reads it)."""

class Imu:
    """The IMU of a run with one."""

    def __init__(
        self,
        rate_hz: float,
        t_bs: Optional[ArrayLike] = None,
        filter: Literal["acc", "gravity", "gyro"] = "acc",
        gyroscope_noise_density: Optional[float] = None,
        gyroscope_random_walk: Optional[float] = None,
        accelerometer_noise_density: Optional[float] = None,
        accelerometer_random_walk: Optional[float] = None,
    ) -> None:
        """An IMU sampled at `rate_hz`. `t_bs`: the camera's pose in the IMU's frame (4×4,
        EuRoC's T_BS); None takes the camera's, from its calibration file. `filter`: the
        paper's model (free acceleration, gravity only, gyroscopes only). The four noise
        densities (EuRoC's imu0/sensor.yaml) go together; without them those of EuRoC's
        ADIS16448, a middle-of-the-road MEMS IMU, are used."""

class FrameReport:
    """What one frame gave."""

    index: int
    """The frame's index (in the order pushed, from 0, unless given)."""
    t: float
    """Its time [s from the tracker's first frame or sample]; NaN for a skipped frame."""
    pose: Optional[Pose]
    """The pose its verdict is on, the core's pose at the frame's time, or None: without an
    IMU the pose estimated with the frame; with one, the pose put out at the frame's time
    (its prediction: the core applies the frame's measurements when they arrive, and its
    poses come at the IMU's rate, `poll_poses()`)."""
    tracked: Optional[bool]
    """Whether it counts as tracked (the model's features registered at that pose, or its
    contour; with an IMU, at the pose they fit, the prediction within 5 cm and 5° of it:
    docs/VISION.md §10); None where it was not analysed (no pose yet, an unusable image)."""
    correspondences: int
    """Correspondences sent to the core (texture features and contour points)."""
    weak: Optional[str]
    """Tracked, with one direction pinned down weakly (one σ beyond half the bound a right
    pose is held to, docs/VISION.md eq. T7): "depth", "sideways", "up-down" (the object's
    position in the camera), "tilt", "pan", "roll about the view" (its orientation); None
    where every direction is pinned, and where not tracked (vision-only, a σ beyond the whole
    bound is not tracked, eq. T9)."""
    skipped: Optional[str]
    """Why the frame could not be used, where it could not (the tracker went on)."""

class Tracker:
    """The tracker: frames (and IMU samples) pushed in, reports polled out.

    Each frame is analysed at the pose predicted for it: the model rendered there, its
    features registered in the frame, the pose corrected. Without a start pose (or after
    `relocate()`, or when the model is lost) a search finds the model in the frames. With
    `live=False` (a recording) a search's answer is taken at the next frame, so that a replay
    gives the same poses every time; with `live=True` at the first frame where it is ready,
    so that a camera is never held up.
    """

    def __init__(
        self,
        model: Model,
        camera: Camera,
        start_pose: Union[Pose, ArrayLike, PathLike, None] = None,
        imu: Optional[Imu] = None,
        *,
        rate_hz: Optional[float] = None,
        link: str = "inproc",
        cache: Optional[PathLike] = None,
        live: bool = False,
        latency_s: float = 0.0,
    ) -> None:
        """A tracker of `model` seen by `camera`.

        start_pose: the camera's pose at the first frame, as a Pose, a 4×4 `cMo` or a start
            pose file; None: the cold start finds it (textured models only).
        imu: the IMU, for a run with one; None: vision only.
        rate_hz: the camera's frame rate (default: the camera file's).
        link: where the fusion core runs: "inproc" (here, f32; "inproc:f64"), "sim" (the
            simulated board on a pty pair), "serial:/dev/ttyACM0[@BAUD]" (a board),
            "tcp:HOST:PORT", "qemu:IMAGE" (the firmware under QEMU).
        cache: the folder of the cold start's viewpoint database (default: the user's cache).
        live: take searches' answers as they come (a camera), not at the next frame (a
            recording, reproducible).
        latency_s: with an IMU, how long after its trigger a frame's measurements reach the
            core, in a replay.
        """
    def push_frame(
        self,
        t: float,
        image: npt.NDArray[np.uint8],
        *,
        index: Optional[int] = None,
        channels: Literal["bgr", "rgb"] = "bgr",
    ) -> None:
        """Pushes the frame taken at `t` [s]: `uint8`, grey H×W or colour H×W×3 (`channels`:
        OpenCV's BGR by default), of the camera's size. Its report comes from `poll()`.

        With an IMU, push each frame just before the IMU sample nearest its time (that sample
        triggered it). ValueError: a wrong dtype, shape or size, or a time not after the last
        frame's."""
    def push_imu(self, t: float, gyro: ArrayLike, accel: ArrayLike) -> None:
        """Pushes the IMU sample taken at `t` [s ≥ 0]: angular rate [rad/s] and specific force
        [m/s²] in the IMU's frame. ValueError: not 3 finite numbers each, or a time not after
        the last sample's (the sample is refused; the tracker goes on)."""
    def poll(self) -> list[FrameReport]:
        """The reports of the frames done since the last call, in order."""
    def poll_poses(self) -> list[Pose]:
        """The core's poses since the last call, in order: with an IMU one per sample, without
        two per frame (the prediction, then the update). The newest 4096 are kept."""
    @property
    def pose(self) -> Optional[Pose]:
        """The core's latest pose (with an IMU: at the last sample), or None."""
    @property
    def state(self) -> Literal["locating", "starting", "tracking", "lost"]:
        """Where the tracker stands: no pose yet; a pose, no frame tracked since; tracking;
        lost (searching)."""
    @property
    def adapter(self) -> str:
        """The renderer's adapter (a GPU, or a software driver)."""
    def relocate(self) -> None:
        """Searches for the model again from the next frame: the pose is known to be wrong.
        TrackerError for an untextured model (nothing to search by)."""
    def finish(self) -> dict[str, Optional[float]]:
        """Ends the run, finishing what is in flight, and returns its figures: `tracked` and
        `judged` frames and their `share` (None where none was judged). The
        tracker takes nothing after; `poll()` and `poll_poses()` give its last reports and
        poses."""
    def __enter__(self) -> "Tracker": ...
    def __exit__(self, *exc: object) -> bool: ...

class Located:
    """What a cold-start attempt found."""

    pose: Optional[Pose]
    """The verified pose, or None."""
    keypoints: int
    matches: int
    inliers: int
    registered: int
    """Features the verification registered at the pose."""
    rms_px: Optional[float]
    """Their reprojection rms [px]."""
    ncc: Optional[float]
    """Rendered-against-live correlation at the pose."""
    ambiguous: bool
    """Whether two plausible poses could not be told apart (both refused)."""
    database: str
    """The viewpoint database's cache file."""
    database_built_because: Optional[str]
    """Why the database was built; None where it was read from the cache."""
    @property
    def accepted(self) -> bool:
        """Whether a pose was accepted."""
    @property
    def times(self) -> dict[str, float]:
        """Stage times [s]: detect, matching, ransac, verify, choose."""

def locate(
    image: npt.NDArray[np.uint8],
    model: Model,
    camera: Camera,
    *,
    cache: Optional[PathLike] = None,
    channels: Literal["bgr", "rgb"] = "bgr",
) -> Located:
    """One cold-start attempt: the model found in `image` with no pose given, as `host-vision
    locate` finds it. The model's viewpoint database is built on its first attempt (minutes on
    two cores) and read back from `cache` after. Only a verified pose is returned."""
