"""The latency cells' ablation (docs/results/consistency.md, "Latency with jitter"): one
observer's median episode NEES/dof, its position RMSE and the controlled state's distance
from zero under latency, with one part of a filter switched or scaled per variant:

    python benchmarks/latency_consistency_ablation.py --env BallTable-v0 \\
        --observer kf-latency-measurements --latency-s 0.15 --seeds 100-107 \\
        --variants "as it is,ball Q x 0.25,no pushes"

Variants (each patches module constants or a method in a process of its own, so the
rows are paired on the same seeds):

- ``as it is``;
- ``ball Q x 0.25``: BallTable ``kf``'s ball filter predicts with a quarter of its Q;
- ``tilt rate noise 0.002``: BallTable's tilt lag model with 0.002 rad/s of rate noise;
- ``no pushes``: the env's ``push_rate_hz`` 0 (the env, not the filter);
- ``ekf without the lever arm``: BallTable ``ekf``'s rotation term about the ball's
  centre height on both axes (what it was before issue 45);
- ``no frame age in the report``: TargetFollower's delivery-time filters report their
  covariance without the frame's age (what they did before issue 45);
- ``pushes' Q x 0.25``: BallTable ``kf``'s ball filter claims a quarter of the pushes'
  share of w1 (the env's pushes unchanged);
- ``floor x 0.5``: BallTable ``kf``'s model error floor ``KF_ACCEL_FLOOR_MPS2`` halved
  (a quarter of its variance, in w1, w2 and w2's start);
- ``motion terms x 0.25``: BallTable ``kf``'s motion model error
  (``motion_model_error_q``) at a quarter of its variance;
- ``tilt Q 0.02 rad/s``: BallTable ``kf``'s tilt filter with the white rate noise of
  0.02 rad/s it had before (now the arm's measured departure from the lag model,
  observer.py ``tilt_departure_q``);
- ``pixels at their own float32 spacing``: BallTable ``kf``'s R with each pixel's float32
  rounding at its own spacing (2^-15 to 2^-17 px under 320 px) instead of the bound the
  sensor declares (2^-13 px, that of 1024-2048 px; envs/sensor.py).

Besides the median episode NEES/dof the rows give, for BallTable, the median episode's
split: the ball's (p, v) block per dof, the tilt's per dof, and the ball's over the
calm steps (none of the 10 steps after a push, nor the first 0.3 s).

Each cell is :func:`~observer_gym.train.experiments.consistency_study.measure_consistency`'s
setup (the system's controller, step cap and env options of the consistency study).
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing

import numpy as np

VARIANTS = (
    "as it is",
    "ball Q x 0.25",
    "tilt rate noise 0.002",
    "no pushes",
    "ekf without the lever arm",
    "no frame age in the report",
    "pushes' Q x 0.25",
    "floor x 0.5",
    "motion terms x 0.25",
    "tilt Q 0.02 rad/s",
    "pixels at their own float32 spacing",
)


def _patch(variant: str) -> dict:
    """Apply ``variant``'s patch in this process; the env options it changes."""
    if variant == "ball Q x 0.25":
        from observer_gym.estimation import filters

        predict = filters.KalmanFilter.predict

        def quarter_q(self, Phi, Q, *args, **kwargs):  # the ball filter: 6 or 8 states
            return predict(self, Phi, Q * 0.25 if self.x.size >= 6 else Q, *args, **kwargs)

        filters.KalmanFilter.predict = quarter_q
    elif variant == "tilt rate noise 0.002":
        from observer_gym.estimation.ball_table import models, observer, pixel_ekf

        class Quieter(models.TiltLagModel):
            @classmethod
            def from_arm(cls, position_gain, physics_dt_s, rate_noise_std, dim=2):
                return models.TiltLagModel.from_arm(position_gain, physics_dt_s, 0.002, dim)

        observer.TiltLagModel = Quieter
        pixel_ekf.TiltLagModel = Quieter
    elif variant == "no pushes":
        return {"push_rate_hz": 0.0}
    elif variant == "ekf without the lever arm":
        from observer_gym.estimation.ball_table import models, pixel_ekf

        pixel_ekf.ROTATION_HEIGHTS_M = models.BALL_CENTRE_HEIGHT_M
    elif variant == "no frame age in the report":
        from observer_gym.estimation.target_follower.noise import NoiseRule

        reported = NoiseRule.reported
        NoiseRule.reported = lambda self, P, X_i, image_rate_pxps=None: reported(self, P, X_i)
    elif variant == "pushes' Q x 0.25":
        from observer_gym.estimation.ball_table import noise, observer

        made = noise.ball_process_params

        def quarter_pushes(config, sigma_v_m, accel_std_mps2=None):
            quarter = dataclasses.replace(config, push_rate_hz=0.25 * config.push_rate_hz)
            return made(quarter, sigma_v_m, accel_std_mps2)

        observer.ball_process_params = quarter_pushes
    elif variant == "floor x 0.5":
        from observer_gym.estimation.ball_table import observer

        observer.KF_ACCEL_FLOOR_MPS2 *= 0.5
    elif variant == "motion terms x 0.25":
        from observer_gym.estimation.ball_table import observer

        motion = observer.motion_model_error_q
        observer.motion_model_error_q = lambda *args: 0.25 * motion(*args)
    elif variant == "tilt Q 0.02 rad/s":
        from observer_gym.envs.ball_table.config import BallTableConfig
        from observer_gym.estimation.ball_table import observer

        config = BallTableConfig()
        lag = observer.TiltLagModel.from_arm(config.arm_position_gain, config.physics_dt_s, 0.02)
        observer.tilt_departure_q = lambda alpha, dt_s: lag.matrices(round(dt_s, 9))[2]
    elif variant == "pixels at their own float32 spacing":
        from observer_gym.estimation.ball_table import noise

        jacobian = noise.BallTableNoiseRule._jacobian

        def own_spacing(self, pixels, K, T_world_cam):
            # R = sigma^2 J J^T with J's columns scaled so that it is J diag(s_i^2) J^T
            J = jacobian(self, pixels, K, T_world_cam)
            if J is None or self.pixel_var_px2 == 0.0:
                return J
            bound = 2.0**-26 / 12.0  # the sensor's declared rounding (2^-13 px)^2 / 12
            gaussian = max(self.pixel_var_px2 - bound, 0.0)
            spacing = np.spacing(np.abs(pixels).astype(np.float32)).astype(float)
            return J * np.sqrt((gaussian + spacing**2 / 12.0) / self.pixel_var_px2)

        noise.BallTableNoiseRule._jacobian = own_spacing
    elif variant != "as it is":
        raise ValueError(f"variant {variant!r} is not one of {', '.join(VARIANTS)}")
    return {}


def _split(record: dict, covariances: list, pushed: np.ndarray, dt_s: float) -> tuple:
    """BallTable's episode split: the ball's (p, v) NEES per dof, the tilt's, and the
    ball's over the calm steps (not within 10 steps plus the latency after a push, nor
    the first 0.3 s)."""
    error = np.asarray(record["estimate"]) - np.asarray(record["state"])
    P = np.asarray(covariances, dtype=float)

    def per_dof(idx: slice) -> np.ndarray:
        e = error[:, idx]
        return np.einsum("ki,ki->k", e, np.linalg.solve(P[:, idx, idx], e[..., None])[..., 0])

    ball, tilt = per_dof(slice(0, 4)) / 4.0, per_dof(slice(4, 6)) / 2.0
    lag_steps = round(record["env_config"].get("latency_s", 0.0) / dt_s)
    calm = np.asarray(record["time_s"]) >= 0.3
    for k in np.flatnonzero(pushed):
        calm[k : k + 11 + lag_steps] = False
    return float(ball.mean()), float(tilt.mean()), float(ball[calm].mean())


def one_variant(
    variant: str, env: str, observer: str, latency_s: float, jitter_s: float, seeds: list[int]
) -> str:
    """The table row of ``variant``."""
    from observer_gym.train.experiments import episode
    from observer_gym.train.experiments.consistency_study import SYSTEMS
    from observer_gym.train.experiments.episode import EpisodeSpec, run_episode
    from observer_gym.train.reports.consistency import episode_consistency

    # keep each episode's covariances and push steps for the split (this process only)
    kept: dict = {}
    nees_per_step, keep_where = episode.nees_per_step, episode._keep_where_model_holds

    def keeping_covariances(estimates, covariances, truth):
        kept["covariances"] = [np.asarray(c, dtype=float) for c in covariances]
        return nees_per_step(estimates, covariances, truth)

    def keeping_pushes(record, env_, samples):
        kept["pushed"] = np.array([s.get("push_impulse_ns") is not None for s in samples])
        kept["dt_s"] = env_.config.dt_s if hasattr(env_.config, "dt_s") else 0.02
        return keep_where(record, env_, samples)

    episode.nees_per_step, episode._keep_where_model_holds = keeping_covariances, keeping_pushes
    study = SYSTEMS[env]
    env_kwargs = {**study.env_kwargs, "latency_s": latency_s, "latency_jitter_s": jitter_s}
    env_kwargs.update(_patch(variant))
    ratios, squared, count, distance, splits = [], 0.0, 0, [], []
    for seed in seeds:
        spec = EpisodeSpec.of(
            f"observer_gym/{env}",
            observer,
            study.controller,
            seed,
            max_steps=study.steps,
            env_kwargs=env_kwargs,
        )
        record = run_episode(spec)
        ratios.append(episode_consistency(record)["nees_ratio"])
        error = np.asarray(record["estimate"])[:, :2] - np.asarray(record["state"])[:, :2]
        squared, count = squared + float(np.sum(error**2)), count + error.size
        distance.append(float(np.mean(np.linalg.norm(np.asarray(record["state"])[:, :2], axis=1))))
        if env == "BallTable-v0":
            splits.append(_split(record, kept["covariances"], kept["pushed"], kept["dt_s"]))
    split = " | ".join(f"{v:.3f}" for v in np.median(np.array(splits), axis=0)) if splits else " | "
    return (
        f"| {variant} | {latency_s:g} | {np.median(ratios):.3f} | "
        f"{np.sqrt(squared / count):.4g} | {np.mean(distance):.4g} | {split} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="BallTable-v0")
    parser.add_argument("--observer", default="kf-latency-measurements")
    parser.add_argument("--latency-s", default="0.15", help="comma-separated (s)")
    parser.add_argument("--jitter-s", type=float, default=0.0)
    parser.add_argument("--seeds", default="0-2", help="first-last[,first-last...]")
    parser.add_argument("--variants", default="as it is", help="comma-separated")
    args = parser.parse_args()
    try:
        seeds = [
            seed
            for part in args.seeds.split(",")
            for first, last in [(int(s) for s in (part.split("-") * 2)[:2])]
            for seed in range(first, last + 1)
        ]
    except ValueError:
        parser.error(f"--seeds: {args.seeds!r} is not first-last[,first-last...]")
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        parser.error(f"--variants: {unknown}; allowed: {', '.join(VARIANTS)}")
    context = multiprocessing.get_context("spawn")  # a fresh process per variant's patch
    try:
        latencies = [float(v) for v in args.latency_s.split(",")]
    except ValueError:
        parser.error(f"--latency-s: {args.latency_s!r} is no comma-separated list of numbers")
    jobs = [
        (v, args.env, args.observer, latency, args.jitter_s, seeds)
        for v in variants
        for latency in latencies
    ]
    with context.Pool(1, maxtasksperchild=1) as pool:
        rows = pool.starmap(one_variant, jobs)
    print(
        f"{args.observer} on {args.env}, latency {args.latency_s} s, jitter {args.jitter_s} s, "
        f"seeds {args.seeds}"
    )
    print(
        "| variant | latency (s) | NEES/dof (median) | position RMSE | distance from zero | "
        "ball (p, v) per dof | tilt per dof | ball, calm steps |"
    )
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
