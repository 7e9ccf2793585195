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
  covariance without the frame's age (what they did before issue 45).

Each cell is :func:`~observer_gym.train.experiments.consistency_study.measure_consistency`'s
setup (the system's controller, step cap and env options of the consistency study).
"""

from __future__ import annotations

import argparse
import multiprocessing

import numpy as np

VARIANTS = (
    "as it is",
    "ball Q x 0.25",
    "tilt rate noise 0.002",
    "no pushes",
    "ekf without the lever arm",
    "no frame age in the report",
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
    elif variant != "as it is":
        raise ValueError(f"variant {variant!r} is not one of {', '.join(VARIANTS)}")
    return {}


def one_variant(
    variant: str, env: str, observer: str, latency_s: float, jitter_s: float, seeds: list[int]
) -> str:
    """The table row of ``variant``."""
    from observer_gym.train.experiments.consistency_study import SYSTEMS
    from observer_gym.train.experiments.episode import EpisodeSpec, run_episode
    from observer_gym.train.reports.consistency import episode_consistency

    study = SYSTEMS[env]
    env_kwargs = {**study.env_kwargs, "latency_s": latency_s, "latency_jitter_s": jitter_s}
    env_kwargs.update(_patch(variant))
    ratios, squared, count, distance = [], 0.0, 0, []
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
    return (
        f"| {variant} | {np.median(ratios):.3f} | {np.sqrt(squared / count):.4g} | "
        f"{np.mean(distance):.4g} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="BallTable-v0")
    parser.add_argument("--observer", default="kf-latency-measurements")
    parser.add_argument("--latency-s", type=float, default=0.15)
    parser.add_argument("--jitter-s", type=float, default=0.0)
    parser.add_argument("--seeds", default="0-2", help="first-last")
    parser.add_argument("--variants", default="as it is", help="comma-separated")
    args = parser.parse_args()
    first, last = (int(s) for s in args.seeds.split("-"))
    seeds = list(range(first, last + 1))
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        parser.error(f"--variants: {unknown}; allowed: {', '.join(VARIANTS)}")
    context = multiprocessing.get_context("spawn")  # a fresh process per variant's patch
    jobs = [(v, args.env, args.observer, args.latency_s, args.jitter_s, seeds) for v in variants]
    with context.Pool(1, maxtasksperchild=1) as pool:
        rows = pool.starmap(one_variant, jobs)
    print(
        f"{args.observer} on {args.env}, latency {args.latency_s} s, jitter {args.jitter_s} s, "
        f"seeds {args.seeds}"
    )
    print("| variant | NEES/dof (median) | position RMSE | distance from zero |")
    print("|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
