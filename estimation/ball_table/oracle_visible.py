"""The BallTable observer ``oracle-visible`` (:class:`OracleVisibleObserver`), for analysis
only: it reads the simulator's ground truth, which no real observer has.

The true state (``info["state"]``) at every step whose new frame shows the ball (the image
stage finds its image: the ball is visible, whether or not the table's pose can be
solved), with zero covariance. Otherwise the last such true state predicted: the tilt by
the arm's lag model driven by the applied commands, the ball by the rolling-ball model
with the gravity input of that tilt and the border constraint, and the covariance grown by
both models' process noise (``kf``'s prediction, started at the truth with no error but
the ball's unknown disturbance). Before the ball is first seen it predicts from ``kf``'s
start (ball at the centre, table level, and their priors). So a controller on
``oracle-visible`` pays for the steps without a sight of the ball (occlusions, dropped
frames) but for no estimation error and no latency (a late frame that shows the ball
gives today's truth).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from observer_gym.envs.ball_table import STATE_DIM, BallTableEnv
from observer_gym.estimation.ball_table.frames import FrameReader, finite_or_none
from observer_gym.estimation.ball_table.geometry_stage import BallTableDetector
from observer_gym.estimation.ball_table.models import RollingBallModel, TiltLagModel
from observer_gym.estimation.ball_table.observer import BallTableObserverParams, TiltBallFilters
from observer_gym.estimation.observer import Estimate

__all__ = ["OracleVisibleObserver"]


class OracleVisibleObserver:
    """``oracle-visible`` for BallTable-v0: see the module docstring.

    Args:
        env: the (unwrapped) env, made with ``obs_mode="rgb"`` or ``"measurements"``.
        params: ``kf``'s parameters: its process models' noise and its start's priors.
        detector: unused (the image stage alone decides what is seen); for the common
            signature.
    """

    def __init__(
        self,
        env: BallTableEnv,
        params: BallTableObserverParams | None = None,
        detector: BallTableDetector | None = None,
    ) -> None:
        # The full recursion: P starts at 0 and grows, no converged-gain path to take.
        self.params = dataclasses.replace(params or BallTableObserverParams(), converged_rtol=None)
        cfg = env.config
        self.ball_model = RollingBallModel(self.params.ball)
        self.tilt_model = TiltLagModel.from_arm(
            cfg.arm_position_gain, cfg.physics_dt_s, self.params.tilt_rate_noise_std_radps
        )
        self.reader = FrameReader(env, detector, type(self).__name__)
        self.reset()

    def reset(self) -> None:
        self.reader.reset()
        self.prediction: TiltBallFilters | None = None

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        frame, obs = self.reader.new_frame(obs, info)
        features = self.reader.features(obs, frame) if frame is not None else None
        time_s = float(info["time_s"])
        models = (self.params, self.ball_model, self.tilt_model, time_s)
        if features is not None and finite_or_none(features.ball_px) is not None:
            truth = np.asarray(info["state"], dtype=float)
            command = self._command(action)
            self.prediction = TiltBallFilters.at_state(*models, truth, command)
            return Estimate(truth.copy(), np.zeros((STATE_DIM, STATE_DIM)), True, features, time_s)
        if self.prediction is None:  # the ball not seen yet: kf's start
            self.prediction = TiltBallFilters(*models, None, None)
        self.prediction.predict_to(time_s, action)
        core = self.prediction
        return Estimate(core.mean(), core.covariance(), False, features, time_s)

    def _command(self, action: np.ndarray | None) -> np.ndarray | None:
        """The command the arm follows now: this step's, else the last one known."""
        if action is not None:
            return np.asarray(action, dtype=float)
        return None if self.prediction is None else self.prediction.tilt_cmd
