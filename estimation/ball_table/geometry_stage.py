"""The BallTable detector's geometry stage (features + calibration ->
:class:`BallTableDetection`), :class:`BallTableDetector`: PnP for the table's pose (table
step 5), then the ball's position on the table (ball steps 2-4), docs/spec/table_ball.md,
"Vision pipeline".

The image stage's corners are good to 0.24 px RMS, which costs ~12 mrad of tilt RMSE when
the red top's square is the only model: seen nearly head-on, a square's tilt is
ill-conditioned. The borders' outer outline, 3 cm higher, is found beside it in every
clean frame, and the pose from all 8 corners (not coplanar; SQPNP) brings the tilt RMSE to
2.8 mrad and the ball's to 0.30 mm. Measured RMSE of tilt / ball position on the table
(tests/estimation/test_ball_table_detector.py, 155 rendered 320x240 frames, fixed camera
and head motion, tilts within +-0.08 rad):

- default (red top + outline, 8 corners):       2.8 mrad / 0.30 mm
- red top alone (``use_outline=False``), IPPE:  12.4 mrad / 0.99 mm
- red top alone (``use_outline=False``), AP3P:  17.3 mrad / 1.14 mm
- ``ball_radius="unknown"``: 0.31 mm, r within -0.39 ... +0.59 mm of 25 mm
- perfect features (measurements obs_mode): worst frame < 0.001 mrad / 0.13 mm
- outline alone (a red corner painted over): 8.1 mrad

IPPE_SQUARE has the lower tilt error, so it is the default ``pnp_method``; with the
outline both methods give the same pose (the square's PnP only runs when the joint pose
fails, to tell why). A pose or ball position that does not hold together (corners that
are no square or disagree with the outline, tilt > 0.35 rad, yaw > 0.1 rad, one square of
a rendered frame less than MIN_SQUARE_SIDE_PX a side on its own, a ball whose image size
does not fit its distance) gives "not found" with the reason
(``BallTableDetection.failure``).

From 84 x 84 frames (focal length 42 px: the red top ~30 px a side, the borders ~1 px
wide) the default detector gives 16.5 and 5.5 mrad of tilt RMSE and 2.1 mm of ball
(tests/estimation/test_ball_table_small_frames.py).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from observer_gym.envs.ball_table import geometry as geo
from observer_gym.estimation.ball_table.features import (
    BORDER_OUTLINE,
    RED_TOP,
    BallTableDetection,
    BallTableFeatures,
)

PNP_METHODS = {"ippe_square": cv2.SOLVEPNP_IPPE_SQUARE, "ap3p": cv2.SOLVEPNP_AP3P}
# Corner reprojection bounds, measured on 492 clean rendered frames: RMS over the 4 corners
# of the PnP pose <= 0.75 px (IPPE_SQUARE) and <= 1.21 px (AP3P, which fits 3 corners
# exactly and leaves the 4th all the error); the largest of the 8 corners of the joint
# pose <= 0.63 px.
MAX_SQUARE_RMS_PX = 1.5
MAX_JOINT_REPROJECTION_PX = 1.0
MAX_PLAUSIBLE_TILT_RAD = 0.35  # the env allows at most 0.3 rad of commanded tilt
MAX_PLAUSIBLE_YAW_RAD = 0.1  # the arm keeps the table at its home yaw
BALL_DISTANCE_TOLERANCE = 0.2  # r known: |d / |p1 - t'| - 1| bound (a partly hidden ball)
# A square's own pose from a rendered frame (no outline beside the red top, or
# ``use_outline=False``) pins the tilt to about 3-5 rad px / its side in px: with the
# occluder and head motion, the worst tilt errors measured were 24 mrad at 320x240 (sides
# ~120 px), 58 mrad at 160x120 (~60 px) and 173 mrad at 84x84 (~30 px). A square with a
# shorter mean side than this gives no pose (perfect features, measurements mode, do).
MIN_SQUARE_SIDE_PX = 50.0


def _model_square(model: str) -> tuple[float, float]:
    """(side, height above the top) of the square whose corners ``model`` names."""
    if model == BORDER_OUTLINE:
        return geo.TABLE_SIDE_M + 2.0 * geo.BORDER_WIDTH_M, geo.BORDER_HEIGHT_M
    return geo.TABLE_SIDE_M, 0.0


_CORNER_SIGNS = np.sign(geo.TABLE_CORNERS_TABLE[:, :2])
# IPPE_SQUARE's object points are (-s/2, s/2), (s/2, s/2), (s/2, -s/2), (-s/2, -s/2): in
# TABLE_CORNERS_TABLE order ((+,+), (-,+), (-,-), (+,-)) those are corners 1, 0, 3, 2.
_IPPE_ORDER = [1, 0, 3, 2]


def model_corners_table(model: str) -> np.ndarray:
    """(4, 3) corners of ``model`` in the table frame, in TABLE_CORNERS_TABLE order."""
    side, height = _model_square(model)
    return np.column_stack([0.5 * side * _CORNER_SIGNS, np.full(4, height)])


# The joint pose's 8 corners: red top, then outline. They are not coplanar, so the joint
# pose is solved by SQPNP (global; on 492 rendered frames it matched cv2.solvePnPRefineLM
# from the square's pose to 0.1 mrad of tilt RMSE, at a third of its cost).
_JOINT_CORNERS_TABLE = np.vstack(
    [model_corners_table(RED_TOP), model_corners_table(BORDER_OUTLINE)]
)
_CORNERS_TABLE = {
    RED_TOP: model_corners_table(RED_TOP).tolist(),
    BORDER_OUTLINE: model_corners_table(BORDER_OUTLINE).tolist(),
    "joint": _JOINT_CORNERS_TABLE.tolist(),
}


def _pnp_square(model: str, flag: int) -> tuple[np.ndarray, list[int] | None]:
    """The model's square at z = 0 (its own frame) and the image-point order for ``flag``."""
    square = np.column_stack([0.5 * _model_square(model)[0] * _CORNER_SIGNS, np.zeros(4)])
    if flag == cv2.SOLVEPNP_IPPE_SQUARE:
        return square[_IPPE_ORDER], _IPPE_ORDER
    return square, None


_PNP_SQUARES = {
    (model, flag): _pnp_square(model, flag)
    for model in (RED_TOP, BORDER_OUTLINE)
    for flag in PNP_METHODS.values()
}


def _reprojection_px(points_table: list, corners_px: np.ndarray, K, R_cam_table, t_cam_table):
    """Each corner's reprojection error, px (inf if a corner is behind the camera). Plain
    Python floats: a few points, where NumPy's per-call cost would dominate."""
    (r0, r1, r2), (tx, ty, tz) = R_cam_table.tolist(), t_cam_table.tolist()
    (fx, _, cx), (_, fy, cy), _ = K.tolist()
    errors = []
    for (x, y, z), (u, v) in zip(points_table, corners_px.tolist(), strict=True):
        depth = r2[0] * x + r2[1] * y + r2[2] * z + tz
        if depth <= 0.0:
            return [math.inf]
        u_hat = fx * (r0[0] * x + r0[1] * y + r0[2] * z + tx) / depth + cx
        v_hat = fy * (r1[0] * x + r1[1] * y + r1[2] * z + ty) / depth + cy
        errors.append(math.hypot(u_hat - u, v_hat - v))
    return errors


def _mean_side_px(corners_px: np.ndarray) -> float:
    """The mean side of the quadrilateral ``corners_px`` (4, 2), px."""
    (a, b, c, d) = corners_px.tolist()
    return 0.25 * (math.dist(a, b) + math.dist(b, c) + math.dist(c, d) + math.dist(d, a))


def _rms(values: list[float]) -> float:
    return math.sqrt(sum(value * value for value in values) / len(values))


class BallTableDetector:
    """The geometry stage: table pose by PnP, ball position on the table.

    Args:
        pnp_method: "ippe_square" (default: IPPE for a planar square; the lower tilt error
            on rendered frames, see the module docstring) or "ap3p" (the report's).
        ball_radius: "known" (r = BALL_RADIUS_M: the ball's centre is where its viewing ray
            meets the plane z_table = r) or "unknown" (r and d both from p1_z = r and
            d = r / sin(alpha), the report's choice).
        use_outline: when the features hold the borders' outline beside the red top,
            solve the pose again on all 8 corners (SQPNP), once the square's PnP has
            vouched for the red top. The outline lies 3 cm above the top, and these
            non-coplanar points pin the tilt far better than one square seen nearly
            head-on (see the module docstring).
    """

    def __init__(
        self, pnp_method: str = "ippe_square", ball_radius: str = "known", use_outline: bool = True
    ) -> None:
        if pnp_method not in PNP_METHODS:
            raise ValueError(f"pnp_method must be one of {sorted(PNP_METHODS)}, got {pnp_method!r}")
        if ball_radius not in ("known", "unknown"):
            raise ValueError(f"ball_radius must be 'known' or 'unknown', got {ball_radius!r}")
        self.pnp_method = pnp_method
        self.ball_radius = ball_radius
        self.use_outline = use_outline
        self._flag = PNP_METHODS[pnp_method]

    def detect(
        self, features: BallTableFeatures, K: np.ndarray, T_world_cam: np.ndarray
    ) -> BallTableDetection:
        """Table pose and ball position from the image stage's features."""
        if features.corners_px is None:
            return BallTableDetection(False, False, failure=f"table: {features.table_failure}")
        pose = self.table_pose(features, K)
        if isinstance(pose, str):
            return BallTableDetection(False, False, features.corner_model, failure=pose)
        R_cam_table, t_cam_table, reprojection_px = pose
        T_cam_table = np.eye(4)
        T_cam_table[:3, :3], T_cam_table[:3, 3] = R_cam_table, t_cam_table
        T_world_table = T_world_cam @ T_cam_table
        R_world_table = T_world_table[:3, :3]
        tilt_x, tilt_y = geo.tilt_angles(R_world_table)  # TRF is parallel to the world at home
        yaw_rad = math.atan2(R_world_table[1, 0], R_world_table[0, 0])
        if (
            max(abs(tilt_x), abs(tilt_y)) > MAX_PLAUSIBLE_TILT_RAD
            or abs(yaw_rad) > MAX_PLAUSIBLE_YAW_RAD
        ):
            return BallTableDetection(
                False, False, features.corner_model, failure="table: implausible pose"
            )
        table = {
            "corner_model": features.corner_model,
            "R_cam_table": R_cam_table,
            "t_cam_table": t_cam_table,
            "T_world_table": T_world_table,
            "tilt_rad": np.array([tilt_x, tilt_y]),
            "up_in_table": R_world_table[2].copy(),  # Z_gnd,table = R_world_table^T e_z
            "corner_reprojection_px": reprojection_px,
        }
        if features.ball_px is None:
            return BallTableDetection(
                True, False, **table, failure=f"ball: {features.ball_failure}"
            )
        ball = self.ball_position(features.ball_px, K, R_cam_table, t_cam_table)
        if isinstance(ball, str):
            return BallTableDetection(True, False, **table, failure=ball)
        position, radius, distance = ball
        return BallTableDetection(
            True,
            True,
            **table,
            ball_pos_table_m=position,
            ball_radius_m=radius,
            ball_distance_m=distance,
        )

    def table_pose(self, features: BallTableFeatures, K: np.ndarray):
        """Table step 5: PnP -> (R_cam_table, t_cam_table, RMS corner reprojection px), or
        the reason the pose was rejected.

        With the outline beside the red top, the joint 8-corner pose comes first: when it
        fits every corner within MAX_JOINT_REPROJECTION_PX it also vouches for the red top
        (the square's own PnP could only fit its 4 corners better, well within
        MAX_SQUARE_RMS_PX), so the square's PnP only runs when the joint pose fails, to
        tell why: the red top is no square, or it and the outline disagree.
        """
        corners_px, model = features.corners_px, features.corner_model
        if corners_px is None or model is None:  # detect() asks only with the corners found
            return f"table: {features.table_failure}"
        outline = features.outline_corners_px
        if self.use_outline and model == RED_TOP and outline is not None:
            joint = self._joint_pose(np.concatenate((corners_px, outline)), K)
            if not isinstance(joint, str):
                return joint
            square = self._square_pose(corners_px, model, K)
            return square if isinstance(square, str) else joint
        if features.source == "image" and not _mean_side_px(corners_px) >= MIN_SQUARE_SIDE_PX:
            return "table: one square too small for a pose"
        return self._square_pose(corners_px, model, K)

    def _square_pose(self, corners_px: np.ndarray, model: str, K: np.ndarray):
        """The pose from one model's 4 corners (``pnp_method``), or why it was rejected."""
        square_points, image_order = _PNP_SQUARES[(model, self._flag)]
        image_points = corners_px[image_order] if image_order is not None else corners_px
        ok, rvec, tvec = cv2.solvePnP(square_points, image_points, K, None, flags=self._flag)
        if not ok:
            return "table: PnP failed"
        R_cam_table, _ = cv2.Rodrigues(rvec)
        height = _model_square(model)[1]
        t_cam_table = tvec.reshape(3) - height * R_cam_table[:, 2]  # square at z = height
        errors_px = _reprojection_px(_CORNERS_TABLE[model], corners_px, K, R_cam_table, t_cam_table)
        if not _rms(errors_px) <= MAX_SQUARE_RMS_PX:
            return "table: corners are no square"
        return R_cam_table, t_cam_table, _rms(errors_px)

    @staticmethod
    def _joint_pose(points_px: np.ndarray, K: np.ndarray):
        """The pose from the red top's and the outline's 8 corners (SQPNP), or why it was
        rejected."""
        ok, rvec, tvec = cv2.solvePnP(
            _JOINT_CORNERS_TABLE, points_px, K, None, flags=cv2.SOLVEPNP_SQPNP
        )
        if not ok:
            return "table: joint PnP failed"
        R_cam_table, _ = cv2.Rodrigues(rvec)
        t_cam_table = tvec.reshape(3)
        errors_px = _reprojection_px(
            _CORNERS_TABLE["joint"], points_px, K, R_cam_table, t_cam_table
        )
        if not max(errors_px) <= MAX_JOINT_REPROJECTION_PX:
            return "table: red top and border outline disagree"
        return R_cam_table, t_cam_table, _rms(errors_px)

    def ball_position(self, ball_px, K, R_cam_table, t_cam_table):
        """Ball steps 2-4 -> (ball_pos_table_m (2,), r, d), or the reason it was rejected.

        The same geometry as camera_geometry.pixel_ray and ray_plane_intersection through
        the camera's pose in the table frame (tests/estimation check they agree), written
        with plain floats for speed: ~10x cheaper than NumPy on 3-vectors.
        """
        u, v, rho = (float(x) for x in ball_px[:3])
        (fx, _, cx), (_, fy, cy), _ = K.tolist()
        # Step 2: the major axis's vertices c +- rho e, e the unit vector from the principal
        # point toward c (any direction when c is at the principal point).
        norm = math.hypot(u - cx, v - cy)
        ex, ey = ((u - cx) / norm, (v - cy) / norm) if norm > 1e-9 else (1.0, 0.0)
        R, t = R_cam_table.tolist(), t_cam_table.tolist()
        # Step 4's t' = -R^T t: the camera's centre in the table frame.
        eye = [-(R[0][i] * t[0] + R[1][i] * t[1] + R[2][i] * t[2]) for i in range(3)]

        def ray(pu: float, pv: float) -> list[float]:
            """Unit ray R^T K^-1 (pu, pv, 1) in the table frame (step 3; v1 = R^T v0)."""
            x, y = (pu - cx) / fx, (pv - cy) / fy
            d = [R[0][i] * x + R[1][i] * y + R[2][i] for i in range(3)]
            n = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            return [d[0] / n, d[1] / n, d[2] / n]

        v_a, v_b = ray(u + rho * ex, v + rho * ey), ray(u - rho * ex, v - rho * ey)
        cos_2alpha = v_a[0] * v_b[0] + v_a[1] * v_b[1] + v_a[2] * v_b[2]
        sin_alpha = math.sin(0.5 * math.acos(min(max(cos_2alpha, -1.0), 1.0)))  # step 3
        v1 = [v_a[i] + v_b[i] for i in range(3)]  # the centre's ray: along v_a + v_b
        n = math.sqrt(v1[0] * v1[0] + v1[1] * v1[1] + v1[2] * v1[2])
        v1 = [v1[0] / n, v1[1] / n, v1[2] / n]
        if sin_alpha <= 0.0:
            return "ball: no size"
        if self.ball_radius == "known":
            # p1 = t' + s v1 on the plane z_table = r (ray-plane intersection).
            radius = geo.BALL_RADIUS_M
            if v1[2] >= 0.0 or eye[2] <= radius:
                return "ball: its ray misses the table"
            distance = (radius - eye[2]) / v1[2]
            if abs(radius / sin_alpha / distance - 1.0) > BALL_DISTANCE_TOLERANCE:
                return "ball: its image size does not fit its distance (partly hidden?)"
        else:
            # p1_z = t'_z + d v1_z = r with d = r / sin(alpha): r (1 - v1_z / sin a) = t'_z.
            radius = eye[2] / (1.0 - v1[2] / sin_alpha)
            if not 0.0 < radius < 0.5 * geo.TABLE_SIDE_M:
                return "ball: implausible radius"
            distance = radius / sin_alpha  # step 3's d = r / sin(alpha)
        position = np.array([eye[0] + distance * v1[0], eye[1] + distance * v1[1]])
        return position, radius, distance
