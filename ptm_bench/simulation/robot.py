"""The mobile base, its path-following controller and the eight-camera mast (docs/model.md §5).

The base is a MuJoCo body with three joints (slide x, slide y, hinge yaw)
driven by velocity actuators; every control period the controller turns the
route into a unicycle command (forward speed v, yaw rate w) by pure pursuit
and the physics is advanced with ``mj_step``. The poses in a dataset are read
back from the simulated joints, never set by hand. The mast carries cameras
``cam_0``..``cam_7`` at bearings 0, 45, ..., 315 degrees in the robot frame,
each with a horizontal field of view slightly above 45 degrees.

    >>> rig = RigConfig()
    >>> body_xml, actuator_xml = base_mjcf(rig)       # spliced into the floor's MJCF by scene.py
    >>> CAMERA_COUNT, rig.image_height, "cam_7" in body_xml
    (8, 64, True)
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import asdict, dataclass

# mujoco picks its OpenGL backend when it is first imported; imported earlier without MUJOCO_GL it
# has picked GLFW, which needs a display, and offscreen rendering fails (see Rig)
_GL_BACKEND_CHOSEN_WITHOUT_US = "mujoco" in sys.modules and "MUJOCO_GL" not in os.environ
os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco's renderer is imported: headless rendering

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from ptm_bench.world.floorplan import resample_polyline  # noqa: E402

__all__ = ["CAMERA_COUNT", "ControllerConfig", "MAX_CONTROL_STEPS", "Rig", "RigConfig", "Trajectory", "base_mjcf",
           "base_pose", "control_steps", "drive", "place_base"]

CAMERA_COUNT = 8
#: The most control steps a drive may be expected to take (:func:`control_steps`) before one is simulated: about
#: a minute of physics at some 100 us a step (and 14 hours of the robot's time at the default 0.1 s period).
MAX_CONTROL_STEPS = 500_000
JOINTS = ("base_x", "base_y", "base_yaw")


@dataclass(frozen=True)
class RigConfig:
    """The camera mast: eight cameras, 360/8 degrees apart, each ``image_height x image_width`` pixels."""

    image_height: int = 64
    image_width: int = 96
    camera_hfov_deg: float = 50.0  # 45 degrees per camera plus 2.5 degrees of overlap on each side
    mast_height: float = 1.2  # [m] camera height above the floor
    camera_offset: float = 0.06  # [m] cameras sit this far out from the mast axis

    def __post_init__(self):
        for name in ("image_height", "image_width"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 8:
                raise ValueError(f"{name} must be an integer >= 8 pixels, got {value!r}")
        if not 45.0 <= self.camera_hfov_deg < 90.0:
            raise ValueError(f"camera_hfov_deg must be in [45, 90) so neighbouring views overlap, got {self.camera_hfov_deg}")
        if self.mast_height <= 0:
            raise ValueError(f"mast_height must be positive, got {self.mast_height}")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels of each pinhole camera."""
        return (self.image_width / 2) / math.tan(math.radians(self.camera_hfov_deg) / 2)

    @property
    def fovy_deg(self) -> float:
        """Vertical field of view, the quantity MJCF cameras are specified by."""
        return math.degrees(2 * math.atan((self.image_height / 2) / self.focal_px))

    def as_meta(self) -> dict:
        return {**asdict(self), "camera_count": CAMERA_COUNT, "fovy_deg": self.fovy_deg}


@dataclass(frozen=True)
class ControllerConfig:
    """Pure-pursuit path following and the physics schedule."""

    control_period: float = 0.1  # [s] one controller update = one odometry step
    timestep: float = 0.02  # [s] physics step; control_period / timestep substeps per update
    lookahead: float = 0.6  # [m] pure-pursuit look-ahead distance
    max_yaw_rate: float = 1.5  # [rad/s]
    heading_gain: float = 3.0  # yaw rate per radian of heading error

    @property
    def substeps(self) -> int:
        return max(1, int(round(self.control_period / self.timestep)))


@dataclass(frozen=True)
class Trajectory:
    """The base's true state sampled once per control period (index 0 = start)."""

    times: np.ndarray  # (T+1,)
    poses: np.ndarray  # (T+1, 3) world x, y, yaw (unwrapped)
    qpos: np.ndarray  # (T+1, nq) full joint state, for re-rendering a detection


def base_mjcf(rig: RigConfig) -> tuple[str, str]:
    """MJCF fragments (worldbody body, actuators) of the base; ``place_base`` sets its start pose."""
    cameras = []
    for index in range(CAMERA_COUNT):
        bearing = 2 * math.pi * index / CAMERA_COUNT
        c, s = math.cos(bearing), math.sin(bearing)
        cameras.append(
            f'<camera name="cam_{index}" pos="{rig.camera_offset * c:.6f} {rig.camera_offset * s:.6f} '
            f'{rig.mast_height:.4f}" xyaxes="{s:.6f} {-c:.6f} 0 0 0 1" fovy="{rig.fovy_deg:.6f}"/>'
        )
    body = f"""
    <body name="base" pos="0 0 0">
      <joint name="base_x" type="slide" axis="1 0 0"/>
      <joint name="base_y" type="slide" axis="0 1 0"/>
      <joint name="base_yaw" type="hinge" axis="0 0 1"/>
      <geom name="base_chassis" type="box" size="0.3 0.22 0.12" pos="0 0 0.18" mass="20" rgba="0.2 0.2 0.25 1"/>
      <geom name="base_mast" type="cylinder" size="0.03 {(rig.mast_height - 0.35) / 2:.4f}"
            pos="0 0 {0.3 + (rig.mast_height - 0.35) / 2:.4f}" mass="1" rgba="0.3 0.3 0.3 1"/>
      {"".join(cameras)}
    </body>"""
    actuators = """
    <velocity name="drive_x" joint="base_x" kv="400"/>
    <velocity name="drive_y" joint="base_y" kv="400"/>
    <velocity name="drive_yaw" joint="base_yaw" kv="40"/>"""
    return body, actuators


def place_base(model, data, pose) -> None:
    """Put the base's joints at ``pose = (x, y, yaw)`` with zero velocity, and update kinematics."""
    for joint, value in zip(JOINTS, pose):
        data.qpos[model.joint(joint).qposadr[0]] = value
    data.qvel[:] = 0.0
    mujoco.mj_forward(model, data)


def base_pose(model, data) -> np.ndarray:
    """The base's (x, y, yaw) read from its joints."""
    return np.array([data.qpos[model.joint(joint).qposadr[0]] for joint in JOINTS])


class PurePursuit:
    """Follows a polyline by steering towards the point ``lookahead`` metres further along it."""

    RESOLUTION = 0.05  # [m] spacing of the resampled path
    SHARP_TURN = math.radians(100.0)  # a turn sharper than this is a stop-and-turn
    ARRIVED = 0.1  # [m] within this of a stop (or the end) the robot has reached it

    def __init__(self, waypoints: np.ndarray, config: ControllerConfig):
        waypoints = np.asarray(waypoints, dtype=float)
        self.points, corners = resample_polyline(waypoints, self.RESOLUTION)
        segments = np.diff(waypoints, axis=0)
        segments = segments[np.linalg.norm(segments, axis=1) > 1e-9]
        # Sharp turns (a dead end's U-turn) are driven to and turned on the spot: pure pursuit would
        # cut them by up to the look-ahead and never reach the waypoint (nor a place there).
        headings = np.arctan2(segments[:, 1], segments[:, 0])
        turns = np.abs(np.angle(np.exp(1j * np.diff(headings))))
        self.stops = [int(corners[k]) for k in np.flatnonzero(turns > self.SHARP_TURN)] + [len(self.points) - 1]
        self.config = config
        self.index = 0
        self.window = int(math.ceil(2.0 / self.RESOLUTION))
        self.ahead = int(math.ceil(config.lookahead / self.RESOLUTION))

    @property
    def finished(self) -> bool:
        return self.index >= len(self.points) - 1

    def command(self, pose: np.ndarray, speed: float) -> tuple[float, float]:
        """(forward speed, yaw rate) for the current true pose."""
        limit = next(stop for stop in self.stops if stop >= self.index)
        end = min(len(self.points), self.index + self.window, limit + 1)
        nearest = self.index + int(np.argmin(np.linalg.norm(self.points[self.index:end] - pose[:2], axis=1)))
        self.index = max(self.index, nearest)
        if self.index >= limit - 1 and np.linalg.norm(self.points[limit] - pose[:2]) < self.ARRIVED:
            if limit == len(self.points) - 1:
                self.index = limit
                return 0.0, 0.0
            self.index = limit + 1  # arrived at a sharp turn: aim along the next leg
            limit = next(stop for stop in self.stops if stop >= self.index)
        target = self.points[min(limit, self.index + self.ahead)]
        error = math.atan2(target[1] - pose[1], target[0] - pose[0]) - pose[2]
        error = math.atan2(math.sin(error), math.cos(error))
        yaw_rate = float(np.clip(self.config.heading_gain * error, -self.config.max_yaw_rate, self.config.max_yaw_rate))
        remaining = np.linalg.norm(self.points[limit] - pose[:2])
        forward = speed * max(0.0, math.cos(error)) ** 2 * min(1.0, remaining / self.config.lookahead + 0.2)
        return forward, yaw_rate


def control_steps(length: float, speed: float, config: ControllerConfig = ControllerConfig()) -> float:
    """About how many control periods driving ``length`` metres at ``speed`` m/s takes: the work of a drive."""
    return length / (speed * config.control_period)


def drive(model, data, waypoints, speed: float, config: ControllerConfig = ControllerConfig(),
          progress=None) -> Trajectory:
    """Drive the base along ``waypoints`` with ``mj_step`` until the end; the true state per control period.

    ``progress``, if given, is called with the fraction of the path covered.
    """
    controller = PurePursuit(waypoints, config)
    model.opt.timestep = config.timestep
    expected_steps = control_steps(len(controller.points) * PurePursuit.RESOLUTION, speed, config)
    max_steps = int(4 * expected_steps + 200)
    addresses = [model.joint(joint).qposadr[0] for joint in JOINTS]
    velocity_addresses = [model.joint(joint).dofadr[0] for joint in JOINTS]
    actuators = [model.actuator(name).id for name in ("drive_x", "drive_y", "drive_yaw")]
    times, poses, states = [data.time], [data.qpos[addresses].copy()], [data.qpos.copy()]
    for _ in range(max_steps):
        pose = poses[-1]
        forward, yaw_rate = controller.command(pose, speed)
        data.ctrl[actuators] = (forward * math.cos(pose[2]), forward * math.sin(pose[2]), yaw_rate)
        mujoco.mj_step(model, data, nstep=config.substeps)
        times.append(data.time)
        poses.append(data.qpos[addresses].copy())
        states.append(data.qpos.copy())
        if progress is not None:
            progress(controller.index / (len(controller.points) - 1))
        if controller.finished and np.linalg.norm(data.qvel[velocity_addresses]) < 1e-3:
            break
    else:
        raise RuntimeError(f"the base did not reach the end of its route within {max_steps} control steps")
    return Trajectory(np.array(times), np.array(poses), np.array(states))


class Rig:
    """Renders the eight mast cameras offscreen for a given simulation state."""

    def __init__(self, model, rig: RigConfig):
        self.model = model
        self.config = rig
        try:
            self.renderer = mujoco.Renderer(model, rig.image_height, rig.image_width)
        except mujoco.FatalError as error:
            if _GL_BACKEND_CHOSEN_WITHOUT_US:
                raise RuntimeError(
                    "cannot render: mujoco was imported before ptm_bench without MUJOCO_GL set, so it chose GLFW, "
                    "which needs a display; set MUJOCO_GL=egl in the environment (headless), or import ptm_bench "
                    "before mujoco"
                ) from error
            raise
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_FOG] = True  # the haze of ptm_bench.simulation.scene
        self.data = mujoco.MjData(model)
        self.camera_ids = [model.camera(f"cam_{index}").id for index in range(CAMERA_COUNT)]

    def views(self, qpos, light_gain: float = 1.0) -> list[np.ndarray]:
        """The eight (H, W, 3) uint8 views with the base at joint state ``qpos``.

        ``light_gain`` scales the lights and the haze, which is lit by the same lights.
        """
        self.data.qpos[:] = qpos
        mujoco.mj_forward(self.model, self.data)
        lit = (self.model.vis.headlight.ambient, self.model.vis.headlight.diffuse, self.model.light_diffuse,
               self.model.vis.rgba.fog[:3])
        saved = [values.copy() for values in lit]
        for values, original in zip(lit, saved):
            values[:] = original * light_gain
        try:
            images = []
            for camera_id in self.camera_ids:
                self.renderer.update_scene(self.data, camera=camera_id)
                images.append(self.renderer.render().copy())
        finally:
            for values, original in zip(lit, saved):
                values[:] = original
        return images

    def close(self) -> None:
        self.renderer.close()
