"""A recording of an episode to scrub in the rerun viewer (``--rerun FILE.rrd``).

:class:`EpisodeRerun` writes one episode into a ``.rrd`` file with rerun-sdk (the
``[rerun]`` extra) while it runs: after the reset and after every step, :meth:`EpisodeRerun.add`
takes the step's ``info`` and logs, on the one timeline ``sim_time_s`` (the env's
``info["time_s"]``, seconds since the reset):

- ``world/ball/truth`` and ``world/ball/estimate``: the tracked ball's true and estimated
  centre as 3-D points in the world frame (BallTable: the table-frame position placed on
  the table's true pose, ``info["T_world_table"]``; BallCatcher: the state's world
  position), and ``world/ball/estimate/ellipsoid``: the 2-sigma ellipsoid of the estimate's
  position covariance (world frame), from its eigendecomposition;
- ``world/table`` (BallTable) and ``world/box`` (BallCatcher): the body's true pose and, once,
  its visual boxes as PyBullet holds them (``getVisualShapeData``); ``world/robot``: the arm
  as a line through its base and its links' frames (its meshes are not logged);
- ``world/camera<i>/nominal`` and ``world/camera<i>/true``: each camera's pose
  (``T_world_cam``) and pinhole (``K``, so the viewer draws its frustum) as the observer was
  told and as the world's camera was, at every frame the camera delivers; under
  ``true/image`` the delivered image with the video's overlays
  (:class:`~observer_gym.train.reports.video.FrameOverlay`: detection, truth, estimate
  and its 2-sigma ellipse, age, drops), JPEG-encoded with OpenCV;
- ``metrics/estimate_error``: the estimate's position error (mm; TargetFollower: px, as
  the video's strip) and ``metrics/nees`` with ``metrics/nees_dof``: the step's NEES over
  the whole state (:func:`~observer_gym.train.reports.consistency.nees_per_step`), not
  logged on steps where the env says its observers' model does not hold
  (``model_holds_key``); ``metrics/action/<k>``: each entry of the controller's action.

The file carries a default layout for the viewer (a blueprint): the 3-D world beside each
camera's images and the plots.

The file is streamed under a temp name beside it (``.NAME.rrd.tmp-PID``, the house's
pattern) and renamed into place when the episode ends, once its footer reads back whole
(:func:`~observer_gym.train.core.atomic_write.replace_atomically`); an episode that fails
or is interrupted removes the temp (:meth:`EpisodeRerun.abort`).
"""

from __future__ import annotations

import dataclasses
import os
import uuid
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from observer_gym.train.core.atomic_write import WriteError, replace_atomically, temp_path_for
from observer_gym.train.reports.consistency import nees_per_step
from observer_gym.train.reports.episode_frames import delivered_frames
from observer_gym.train.reports.outputs import check_writable_folder
from observer_gym.train.reports.video import (
    ERROR_ENTRIES,
    ESTIMATE_RGB,
    TRUTH_RGB,
    FrameOverlay,
)

APPLICATION_ID = "observer-gym"
TIMELINE = "sim_time_s"
JPEG_QUALITY = 90
BALL_RADIUS_M = 0.025  # BallTable's and BallCatcher's ball (drawn at this radius)
FRUSTUM_DEPTH_M = 0.1
ARM_RGB = (255, 140, 0)  # where the viewer draws each camera's image plane
# The scene's bodies drawn as boxes, per system: the env scene's attribute holding the
# PyBullet body and the info entry holding its true pose (4x4, world from body)
SCENE_BODIES = {
    "ball_table": (("table", "T_world_table"),),
    "ball_catcher": (("box", "T_world_box"),),
}


@dataclasses.dataclass(frozen=True)
class RerunRequest:
    """Where an episode's recording goes (a ``.rrd`` file) and the recording's name."""

    path: str
    name: str


def check_rerun_file(path: str | os.PathLike) -> Path:
    """``path`` checked before any episode runs: ValueError unless it ends in ``.rrd``,
    if it is a folder, or where rerun-sdk's logging is turned off (the environment
    variable ``RERUN`` set to off, 0 or false: rerun would write nothing); its folder
    created if needed, and WriteError (one line) if files
    cannot be made there. Removes the temps there of writers that are gone (a run killed
    with SIGKILL), as :func:`~observer_gym.train.reports.video.check_video_folder` does."""
    path = Path(path)
    _check_rerun_logging()
    if path.suffix != ".rrd":
        raise ValueError(f"--rerun takes a file ending in .rrd, got {str(path)!r}")
    if path.is_dir():
        raise ValueError(f"--rerun {path} is a folder; give a file ending in .rrd")
    check_writable_folder(path.parent, str(path))
    return path


def check_rerun_folder(folder: str | os.PathLike) -> Path:
    """``folder`` for one ``.rrd`` per recorded episode, checked before any episode runs
    as :func:`check_rerun_file` checks a file: ValueError for a name ending in ``.rrd``
    (a folder is asked for) or where rerun-sdk's logging is turned off; created if needed,
    WriteError (one line) if files cannot be made in it, and the temps there of writers
    that are gone removed."""
    folder = Path(folder)
    _check_rerun_logging()
    if folder.suffix == ".rrd":
        raise ValueError(
            f"--rerun takes a folder here (one .rrd per recorded episode), got {str(folder)!r}"
        )
    return check_writable_folder(folder, f"rerun recordings into {folder}")


def _check_rerun_logging() -> None:
    """ValueError where the environment variable ``RERUN`` turns rerun-sdk's logging off.
    rerun-sdk reads it when a recording starts; asked here (its own values) so that the
    run is refused before any episode rather than failing after one."""
    if os.environ.get("RERUN", "").strip().lower() in ("0", "off", "false"):
        raise ValueError(
            f"--rerun: rerun-sdk's logging is turned off here (RERUN={os.environ['RERUN']} "
            "in the environment), so it would write nothing: unset RERUN or set RERUN=on"
        )


@dataclasses.dataclass(frozen=True)
class BallInWorld:
    """The tracked ball's centre in the world frame and, for an estimate, its position
    covariance there (3, 3; m^2)."""

    centre_m: np.ndarray
    covariance_m2: np.ndarray | None


def ball_in_world(
    system: str,
    info: Mapping[str, Any],
    state: np.ndarray,
    covariance: np.ndarray | None = None,
) -> BallInWorld | None:
    """The ball of ``state`` (the env's state layout) in the world frame, None for a
    system without a 3-D ball (TargetFollower's target is tracked in the image).
    BallTable: the table-frame (x, y) at the ball's radius above the top, on the table's
    true pose ``info["T_world_table"]``; its covariance R[:, :2] P R[:, :2]^T (flat along
    the table's normal). BallCatcher: the state's world position and its block of P."""
    state = np.asarray(state, dtype=float)
    if system == "ball_table":
        T = np.asarray(info["T_world_table"], dtype=float)
        centre = T[:3, :3] @ np.array([state[0], state[1], BALL_RADIUS_M]) + T[:3, 3]
        if covariance is None:
            return BallInWorld(centre, None)
        R = T[:3, :2]
        return BallInWorld(centre, R @ np.asarray(covariance)[:2, :2] @ R.T)
    if system == "ball_catcher":
        block = None if covariance is None else np.asarray(covariance)[:3, :3]
        return BallInWorld(state[:3].copy(), block)
    return None


def ellipsoid_axes(covariance_m2: np.ndarray, sigmas: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """The ``sigmas``-sigma ellipsoid of a 3-D covariance: its half sizes (3,) along its
    principal axes and the rotation to them as a quaternion (x, y, z, w)."""
    values, vectors = np.linalg.eigh(0.5 * (covariance_m2 + covariance_m2.T))
    if np.linalg.det(vectors) < 0:  # a proper rotation
        vectors[:, 0] = -vectors[:, 0]
    half_sizes = sigmas * np.sqrt(np.maximum(values, 0.0))
    return half_sizes, Rotation.from_matrix(vectors).as_quat()


def _arm_of(env: Any) -> tuple[Any, int, int] | None:
    """The scene's robot arm as (PyBullet client, body, number of links), None without
    one (TargetFollower)."""
    base = env.unwrapped
    arm = getattr(getattr(base, "scene", None), "arm", None)
    body = getattr(arm, "body", None)
    if body is None:
        return None
    client = base.sim.client
    return client, body, int(client.getNumJoints(body))


def arm_joints_world(arm: tuple[Any, int, int]) -> np.ndarray:
    """The arm's base and each link's frame origin (n + 1, 3) in the world frame, now."""
    client, body, links = arm
    # PyBullet gives the base's centre of mass: its link frame is that times the inverse
    # of the inertial frame's offset
    com_m, com_quat = client.getBasePositionAndOrientation(body)
    inertial_m, inertial_quat = client.getDynamicsInfo(body, -1)[3:5]
    base_m, _ = client.multiplyTransforms(
        com_m, com_quat, *client.invertTransform(inertial_m, inertial_quat)
    )
    states = client.getLinkStates(body, list(range(links)), computeForwardKinematics=True)
    return np.array([base_m, *(state[4] for state in states)], dtype=float)


def _box_shapes(env: Any, attribute: str) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, Any]]:
    """The visual boxes of the scene's body ``attribute``: (half sizes, centre,
    quaternion xyzw, RGBA 0-255) in the body's frame, as PyBullet holds them (the fixed
    links of these bodies share the base's frame)."""
    import pybullet

    base = env.unwrapped
    scene = getattr(base, "scene", None)
    body = getattr(scene, attribute, None)
    if body is None:
        return []
    shapes = []
    for row in base.sim.client.getVisualShapeData(body):
        if row[2] != pybullet.GEOM_BOX:
            continue
        rgba = [round(255 * c) for c in row[7]]
        shapes.append(
            (0.5 * np.asarray(row[3]), np.asarray(row[5]), np.asarray(row[6]), tuple(rgba))
        )
    return shapes


class EpisodeRerun:
    """The recording of one episode, written as the episode runs.

    Call :meth:`add` with the reset's ``info`` (``step`` 0) and each step's, then
    :meth:`finish`; on any failure :meth:`abort` removes the temp (as a context manager:
    ``finish`` on a normal exit, ``abort`` on an exception)."""

    def __init__(self, request: RerunRequest, env: Any) -> None:
        import rerun as rr  # the [rerun] extra, checked before any episode

        from observer_gym.envs import system_of

        self.rr = rr
        self.env = env
        self.path = Path(request.path)
        self.tmp = temp_path_for(self.path)
        base = env.unwrapped
        self.system = system_of(base).name
        self.error_entries = ERROR_ENTRIES.get(self.system)
        self.model_holds_key = getattr(base, "model_holds_key", None)
        self.overlay = FrameOverlay(env)
        self.arm = _arm_of(env)
        self.images_logged = 0
        self.stream = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
        self.stream.set_log_time_enabled(False)  # one timeline: the simulation's
        try:
            self.stream.save(self.tmp, default_blueprint=self._blueprint())
        except Exception as exc:  # rerun reports a file it cannot open as its own error
            self.tmp.unlink(missing_ok=True)
            raise WriteError(f"could not write {self.path}: {exc}") from exc
        self.stream.send_recording_name(request.name)
        self._log_static()

    def _blueprint(self) -> Any:
        """The viewer's default layout: the 3-D world beside each camera's images and the
        error and NEES plots, the time panel on :data:`TIMELINE`."""
        import rerun.blueprint as rrb

        cameras = [
            rrb.Spatial2DView(origin=f"world/camera{i}/true", name=f"camera {i}")
            for i in range(int(self.env.unwrapped.rig.num_cameras))
        ]
        plots = [
            rrb.TimeSeriesView(origin="metrics/estimate_error", name="estimate error"),
            rrb.TimeSeriesView(origin="metrics/nees", name="NEES"),
            rrb.TimeSeriesView(origin="metrics/action", name="action"),
        ]
        return rrb.Blueprint(
            rrb.Horizontal(
                rrb.Spatial3DView(origin="world", name="world"),
                rrb.Vertical(*cameras, *plots),
            ),
            rrb.TimePanel(timeline=TIMELINE),
        )

    def _log_static(self) -> None:
        rr, log = self.rr, self.stream.log
        log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.bodies = SCENE_BODIES.get(self.system, ())
        for attribute, _ in self.bodies:
            shapes = _box_shapes(self.env, attribute)
            if shapes:
                log(
                    f"world/{attribute}/boxes",
                    rr.Boxes3D(
                        half_sizes=[s[0] for s in shapes],
                        centers=[s[1] for s in shapes],
                        quaternions=[rr.Quaternion(xyzw=s[2]) for s in shapes],
                        colors=[s[3] for s in shapes],
                        fill_mode="solid",
                    ),
                    static=True,
                )
        log("metrics/estimate_error", rr.SeriesLines(colors=[ESTIMATE_RGB]), static=True)

    def add(self, info: Mapping[str, Any], step: int, action: np.ndarray | None = None) -> None:
        """Log the step's world, frames and metrics (the reset's with ``step`` 0)."""
        rr, log = self.rr, self.stream.log
        self.stream.set_time(TIMELINE, duration=float(info["time_s"]))
        if action is not None:
            for k, value in enumerate(np.asarray(action, dtype=float).reshape(-1)):
                log(f"metrics/action/{k}", rr.Scalars(float(value)))
        for attribute, key in self.bodies:
            if key in info:
                T = np.asarray(info[key], dtype=float)
                log(f"world/{attribute}", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        if self.arm is not None:
            log("world/robot", rr.LineStrips3D([arm_joints_world(self.arm)], colors=[ARM_RGB]))
        state = np.asarray(info["state"], dtype=float)
        truth = ball_in_world(self.system, info, state)
        if truth is not None:
            log(
                "world/ball/truth",
                rr.Points3D([truth.centre_m], radii=BALL_RADIUS_M, colors=[TRUTH_RGB]),
            )
        estimate = info.get("estimate")
        if estimate is not None:
            self._log_estimate(info, state, estimate)
        for frame in delivered_frames(self.env, info, step):
            for kind, K, T in (
                ("nominal", frame.K, frame.T_world_cam),
                ("true", frame.K_true, frame.T_world_cam_true),
            ):
                entity = f"world/camera{frame.camera_id}/{kind}"
                scale = 1 if frame.image is None else self.overlay.scale_of(frame.image)
                width, height = self.env.unwrapped.rig.image_size_px
                log(
                    entity,
                    rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]),
                    rr.Pinhole(
                        image_from_camera=np.diag([scale, scale, 1.0]) @ K,
                        resolution=[scale * width, scale * height],
                        camera_xyz=rr.ViewCoordinates.RDF,  # OpenCV's: x right, y down
                        image_plane_distance=FRUSTUM_DEPTH_M,
                    ),
                )
            if frame.image is None:
                continue
            drawn = cv2.cvtColor(self.overlay.draw(frame), cv2.COLOR_RGB2BGR)
            ok, jpeg = cv2.imencode(".jpg", drawn, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            if not ok:
                raise WriteError(f"could not write {self.path}: OpenCV could not encode a frame")
            log(
                f"world/camera{frame.camera_id}/true/image",
                rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg"),
            )
            self.images_logged += 1

    def _log_estimate(
        self, info: Mapping[str, Any], state: np.ndarray, estimate: Mapping[str, Any]
    ) -> None:
        rr, log = self.rr, self.stream.log
        mean = np.asarray(estimate["mean"], dtype=float)
        covariance = np.asarray(estimate["covariance"], dtype=float)
        ball = ball_in_world(self.system, info, mean, covariance)
        if ball is not None:
            log(
                "world/ball/estimate",
                rr.Points3D([ball.centre_m], radii=0.5 * BALL_RADIUS_M, colors=[ESTIMATE_RGB]),
            )
            if ball.covariance_m2 is not None and np.all(np.isfinite(ball.covariance_m2)):
                half_sizes, quaternion = ellipsoid_axes(ball.covariance_m2)
                log(
                    "world/ball/estimate/ellipsoid",
                    rr.Ellipsoids3D(
                        centers=[ball.centre_m],
                        half_sizes=[half_sizes],
                        quaternions=[rr.Quaternion(xyzw=quaternion)],
                        colors=[ESTIMATE_RGB],
                    ),
                )
        if self.error_entries is not None:
            entries, _, scale = self.error_entries
            error = float(np.linalg.norm(mean[entries] - state[entries]) * scale)
            if np.isfinite(error):
                log("metrics/estimate_error", rr.Scalars(error))
        if self.model_holds_key is not None and not bool(info.get(self.model_holds_key, True)):
            return
        nees, dof = nees_per_step(mean[None], [covariance], state[None])
        if np.isfinite(nees[0]):
            log("metrics/nees", rr.Scalars(float(nees[0])))
            log("metrics/nees_dof", rr.Scalars(float(dof[0])))

    def finish(self) -> Path:
        """Close the file and move it into place; its path."""

        def close(tmp: Path) -> None:
            from rerun.chunk import RrdReader

            self.stream.flush()
            self.stream.disconnect()  # closes the file sink: the footer is written
            if not tmp.is_file() or tmp.stat().st_size == 0:
                raise OSError(f"rerun wrote nothing to {tmp.name}")
            # rerun's writer reports a failed write (a full disk) in its log, not to the
            # caller: the file is whole if its footer reads back (a few ms)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # rerun's own warning for a missing footer
                try:
                    RrdReader(tmp).store()
                except (RuntimeError, ValueError) as exc:
                    raise OSError(f"the recording is incomplete: {exc}") from exc

        replace_atomically(self.path, close)
        return self.path

    def abort(self) -> None:
        """Close the file and remove the temp; nothing is renamed into place."""
        try:
            self.stream.disconnect()
        except Exception:  # the temp goes whatever rerun says
            pass
        self.tmp.unlink(missing_ok=True)

    def __enter__(self) -> EpisodeRerun:
        return self

    def __exit__(self, kind, value, traceback) -> None:
        if kind is None:
            self.finish()
        else:
            self.abort()
