"""Fit (``--write``) or measure a learned observer's post-hoc variance scale, and the
autocorrelation of its network's error (estimation/learned/variance_scale.py).

Runs the system's controller on an observer's estimate for ``--episodes`` episodes of
validation seeds (``--seed`` onwards; the tests use 10**6 onwards: keep them apart) and
prints the RMSE per state entry, the median NEES/dof (full covariance) and, for
``learned``, the scale per entry (mean of error^2 / variance, against the unscaled
network) and the autocorrelation of the normalised error at lags 1..k (new frames only).
With ``--write``, the scale of ``learned`` goes into the weight file's report under
``variance_scale`` for the obs mode, with this command and the seeds.

``--ranges study`` draws each episode's sensor across the consistency study's ranges
(train/experiments/consistency_study.py, ``OPTIONS``): episode i varies one option,
pixel noise, latency (with the study's jitter) and drops in turn (``--vary`` names
others, such as the calibration errors), drawn uniformly over the study's values' span,
the others at the study's defaults; the episodes' options are
printed with their NEES/dof. In ``--obs-mode rgb`` the episodes vary the frames part's
options in turn instead (``FRAME_SYSTEMS``: ``image_noise_std``, ``latency_s``).
``--estimator geometric`` fits the scale as the geometric mean over episodes of each
episode's mean error^2 / variance (``mean``: the mean over every step), so that the
episodes' NEES/dof sit around 1 on a log scale: the band [1/3, 3] is symmetric in log,
and a few episodes far outside the network's training range (whose mean error^2 /
variance can be 10-100) do not set the scale of all the others. ``--by-age KNOTS``
(with ``--estimator geometric``) fits a scale by the newest frame's age instead
(:func:`~observer_gym.estimation.learned.variance_scale.fit_variance_scale`: log(scale)
piecewise linear over the comma-separated knots, s, against each episode's mean age of
the newest frame received, the step's time minus its capture time, held at the end
knots: steps before the first frame count at the last knot, as the observer's scale
does); the episodes' mean ages and ratios are printed. ``--hold-to AGE_S`` (one of the
knots) keeps the report's scale at the knots up to it and fits the later ones only
(BallCatcher: its constant scale, fitted across every condition, where the frames are
young; written with the held scale's own command before it). ``--by-declared
NAME=KNOTS`` (with ``--by-age``; repeatable) adds a term by each episode's declared
sensor number NAME (a field of ``env.sensor_spec``, the data sheet ``kf``'s R reads, such
as ``measurement_noise_std_px``), log-linear over those knots and 1 at the first, fitted
jointly with the age; the observer then reads that number of its env's declared sensor.

    python benchmarks/learned_variance_scale.py --env BallTable-v0 --obs-mode measurements \
        --observer learned --seed 2000000 --episodes 6 --write
    python benchmarks/learned_variance_scale.py --env BallTable-v0 --observer learned \
        --seed 3000000 --episodes 36 --ranges study --estimator geometric \
        --by-age 0,0.05,0.1,0.15,0.2 --write
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from importlib import import_module
from typing import Any

import gymnasium as gym
import numpy as np

from observer_gym.controllers import make_controller
from observer_gym.envs.ball_catcher.layout import BALL
from observer_gym.envs.target_follower import StateIndex
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.learned.variance_scale import (
    SENSOR_FIELDS,
    VARIANCE_SCALE_KEY,
    fit_variance_scale,
    load_variance_scale,
)
from observer_gym.train.core.args import Parser
from observer_gym.train.reports.outputs import write_text_atomic

# env id -> (learned module, controller, steps per episode, options of the episodes, the
# state entries compared: the network's outputs)
SYSTEMS: dict[str, tuple[str, str, int, dict[str, Any], slice]] = {
    "BallTable-v0": (
        "observer_gym.estimation.ball_table.learned",
        "lqr",
        300,
        {"measurement_noise_px": 1.0},
        slice(0, 8),
    ),
    "TargetFollower-v0": (
        "observer_gym.estimation.target_follower.learned",
        "vtc",
        300,
        {"measurement_noise_px": 2.0},
        slice(0, 6),
    ),
    "BallCatcher-v1": (
        "observer_gym.estimation.ball_catcher.learned",
        "intercept",
        10**6,  # one throw: until the episode ends
        {"measurement_noise_px": 1.0},
        BALL,
    ),
}
FROM_S = 0.1  # BallCatcher: errors from this long after the launch to the box's plane
RANGED = ("measurement_noise_px", "latency_s", "frame_drop_prob")  # --ranges study, in turn


def episode_options(args: argparse.Namespace, seed: int, base: dict[str, Any]) -> dict[str, Any]:
    """The env options of the episode of ``seed``: ``base`` (``--ranges fixed``), or the
    study's defaults with one option of :data:`RANGED` drawn over the study's span (rgb:
    one of the frames part's options, ``FRAME_SYSTEMS``, over its span)."""
    if args.ranges == "fixed":
        return dict(base)
    from observer_gym.train.experiments import consistency_study as study

    # rgb: the frames part's options and values (image noise, latency), not the pixels'
    ranges = study.FRAME_SYSTEMS[args.env].options if args.obs_mode == "rgb" else study.OPTIONS
    ranged = tuple(ranges) if args.obs_mode == "rgb" else tuple(args.vary)
    key = ranged[(seed - args.seed) % len(ranged)]
    low, high = min(ranges[key]), max(ranges[key])
    value = float(np.random.default_rng(seed).uniform(low, high))
    env_kwargs = study.SYSTEMS[args.env].env_kwargs
    return {**env_kwargs, **study.OPTION_ENV_KWARGS.get(key, {}), key: value}


def run(args: argparse.Namespace) -> dict[str, Any]:
    module_name, controller_name, steps, options, entries = SYSTEMS[args.env]
    steps = args.steps or steps
    options = {} if args.obs_mode == "rgb" else dict(options)
    if args.noise_px is not None:
        options["measurement_noise_px"] = args.noise_px
    kwargs = {} if args.fuse_every is None else {"fuse_every": args.fuse_every}
    if args.r_inflation is not None:
        kwargs["r_inflation"] = args.r_inflation
    errors, variances, nees, new_frame, episode, ages_s = [], [], [], [], [], []
    declared: list[dict[str, float]] = []  # each step's declared sensor numbers
    catches = 0
    drawn = []
    for seed in range(args.seed, args.seed + args.episodes):
        episode_kwargs = episode_options(args, seed, options)
        drawn.append(episode_kwargs)
        env = VisionObserver(
            gym.make(f"observer_gym/{args.env}", obs_mode=args.obs_mode, **episode_kwargs),
            observer=args.observer,
            **kwargs,
        )
        try:
            spec = env.unwrapped.sensor_spec
            numbers = {name: float(getattr(spec, name)) for name in SENSOR_FIELDS}
            controller = make_controller(controller_name, env)
            estimate, info = env.reset(seed=seed)
            newest_capture_s = -np.inf  # the newest frame received so far
            for _ in range(steps):
                if hasattr(controller, "observe_info"):
                    controller.observe_info(info)  # the intercept reads the throw's timing
                action, _ = controller.predict(estimate, deterministic=True)
                estimate, _, terminated, truncated, info = env.step(action)
                if terminated or truncated:
                    catches += bool(info.get("caught", False))
                    break
                for frame in info["frames"]:
                    newest_capture_s = max(newest_capture_s, float(frame["capture_time_s"]))
                state = info["state"]
                if args.env == "BallCatcher-v1" and not (
                    info["ball_in_flight"]
                    and FROM_S <= info["time_s"] < info["throw"]["crossing_time_s"]
                ):
                    continue  # the free flight only
                if args.env == "TargetFollower-v0" and (
                    state[StateIndex.TRACKING_VALID] < 0.5
                    or estimate[StateIndex.TRACKING_VALID] < 0.5
                ):
                    continue  # the image state is defined while the target is tracked
                e = (info["estimate"]["mean"] - state)[entries]
                P = info["estimate"]["covariance"][entries, entries]
                errors.append(e)
                variances.append(np.diag(P).copy())
                nees.append(e.dot(np.linalg.solve(P, e)) / len(e))
                new_frame.append(bool(info["estimate"]["measurement_used"]))
                episode.append(seed - args.seed)
                ages_s.append(float(info["time_s"]) - newest_capture_s)  # inf: no frame yet
                declared.append(numbers)
        finally:
            env.close()
    e, var = np.array(errors), np.array(variances)
    out: dict[str, Any] = {
        "rmse": np.sqrt(np.mean(e**2, axis=0)).tolist(),
        "nees_per_dof_median": float(np.median(nees)),
        "steps": len(e),
    }
    if args.env == "BallCatcher-v1":
        out["catches"] = catches
    episode_of = np.array(episode)
    if args.ranges == "study":
        out["episodes"] = [
            {
                "seed": args.seed + i,
                "options": drawn[i],
                "nees_per_dof_median": float(np.median(np.array(nees)[episode_of == i]))
                if np.any(episode_of == i)
                else None,
            }
            for i in range(args.episodes)
        ]
    if args.observer == "learned":
        module = import_module(module_name)
        report = json.loads(module.WEIGHTS.with_suffix(".json").read_text())
        old = load_variance_scale(report, args.obs_mode, e.shape[1])
        ages = np.array(ages_s)
        raw_var = var / np.array([old.at(a, d) for a, d in zip(ages, declared, strict=True)])
        ratio = e**2 / raw_var
        if args.estimator == "mean":
            out["scale"] = np.mean(ratio, axis=0).tolist()
        else:  # each episode's mean, over the episodes: geometric mean, or by the age
            indices = np.unique(episode_of)
            per_episode = np.array([ratio[episode_of == i].mean(axis=0) for i in indices])
            if args.by_age is None:
                out["scale"] = np.exp(np.mean(np.log(per_episode), axis=0)).tolist()
            else:
                # ages beyond the end knots (and before the first frame) count at them
                clipped = np.clip(ages, args.by_age[0], args.by_age[-1])
                mean_age_s = np.array([clipped[episode_of == i].mean() for i in indices])
                # each episode's declared numbers (one sensor an episode)
                first = [int(np.flatnonzero(episode_of == i)[0]) for i in indices]
                by = {
                    name: (np.array([declared[j][name] for j in first]), knots)
                    for name, knots in (args.by_declared or {}).items()
                }
                # --hold-to: the report's scale up to that age stays (fitted before, across
                # every condition); the age adds what the later episodes measure
                held = None if args.hold_to is None else (args.hold_to, old.at(args.hold_to))
                fitted = fit_variance_scale(mean_age_s, per_episode, args.by_age, held, by)
                out["scale"] = fitted.to_entry()
                out["episodes_by_age"] = [
                    {
                        "seed": args.seed + int(i),
                        "mean_age_s": float(age),
                        "declared": {name: declared[j][name] for name in by},
                        "ratio": ratio_i.tolist(),
                        "fitted": fitted.at(age, declared[j]).tolist(),
                    }
                    for i, j, age, ratio_i in zip(
                        indices, first, mean_age_s, per_episode, strict=True
                    )
                ]
        z = (e / np.sqrt(raw_var))[np.array(new_frame)]
        z = z - z.mean(axis=0)
        out["autocorrelation_lag_1_to_8"] = [
            float(np.mean(np.sum(z[lag:] * z[:-lag], axis=0) / np.sum(z * z, axis=0)))
            for lag in range(1, 9)
        ]
        if args.write:
            path = module.WEIGHTS.with_suffix(".json")
            report = json.loads(path.read_text())
            entry = report.setdefault(VARIANCE_SCALE_KEY, {})
            entry[args.obs_mode] = out["scale"]
            command = "python " + shlex.join(sys.argv)
            commands = entry.setdefault("commands", {})
            if args.hold_to is not None and args.obs_mode in commands:
                # the held part's own command first: the two together re-make the scale
                command = commands[args.obs_mode].split(" && ")[0] + " && " + command
            commands[args.obs_mode] = command
            path_text = json.dumps(report, indent=2) + "\n"
            write_text_atomic(path, path_text)
    return out


def knots_arg(text: str) -> list[float]:
    """``--by-age``'s knots: comma-separated ages >= 0 s, strictly increasing."""
    try:
        knots = [float(part) for part in text.split(",")]
    except ValueError:
        knots = []
    if not knots or any(k < 0 or not np.isfinite(k) for k in knots) or knots != sorted(set(knots)):
        raise argparse.ArgumentTypeError(
            f"knots must be comma-separated, strictly increasing ages >= 0 s, got {text!r}"
        )
    return knots


def vary_arg(text: str) -> list[str]:
    """``--vary``'s options: comma-separated names of the consistency study's options."""
    from observer_gym.train.experiments.consistency_study import OPTIONS

    names = text.split(",")
    if not names or any(name not in OPTIONS for name in names) or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(
            f"options must be comma-separated, distinct names of the study's options, "
            f"{', '.join(OPTIONS)}; got {text!r}"
        )
    return names


def declared_arg(text: str) -> tuple[str, list[float]]:
    """``--by-declared``'s NAME=KNOTS: a declared sensor number and its knots."""
    name, _, knots = text.partition("=")
    if name not in SENSOR_FIELDS:
        raise argparse.ArgumentTypeError(
            "NAME must be a number of the declared sensor, one of "
            f"{', '.join(sorted(SENSOR_FIELDS))}; got {text!r}"
        )
    try:
        return name, knots_arg(knots)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"{name}'s knots must be comma-separated, strictly increasing values >= 0, "
            f"got {knots!r}"
        ) from None


def main(argv: list[str] | None = None) -> int:
    parser = Parser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", required=True, choices=sorted(SYSTEMS))
    parser.add_argument("--obs-mode", default="measurements", choices=["measurements", "rgb"])
    parser.add_argument("--observer", default="learned")
    parser.add_argument("--seed", type=int, default=2 * 10**6)
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--steps", type=int, default=0)
    parser.add_argument("--fuse-every", type=int, default=None)
    parser.add_argument("--r-inflation", type=float, default=None, help="learned-kf's R factor")
    parser.add_argument("--noise-px", type=float, default=None)
    parser.add_argument("--ranges", default="fixed", choices=["fixed", "study"])
    parser.add_argument("--estimator", default="mean", choices=["mean", "geometric"])
    parser.add_argument(
        "--vary",
        type=vary_arg,
        default=list(RANGED),
        metavar="OPTIONS",
        help="with --ranges study, from measurements: the study's options the episodes "
        f"vary in turn, comma-separated (default: {','.join(RANGED)})",
    )
    parser.add_argument(
        "--by-age",
        type=knots_arg,
        default=None,
        metavar="KNOTS",
        help="fit the scale by the newest frame's age over these comma-separated knots (s)",
    )
    parser.add_argument(
        "--hold-to",
        type=float,
        default=None,
        metavar="AGE_S",
        help="with --by-age: hold the report's scale at the knots up to this one (s) and "
        "fit the later knots only",
    )
    parser.add_argument(
        "--by-declared",
        type=declared_arg,
        action="append",
        default=None,
        metavar="NAME=KNOTS",
        help="with --by-age: add a term by the declared sensor's number NAME (a "
        "SensorSpec field) over these comma-separated knots, fitted jointly with the age "
        "(repeatable)",
    )
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args(argv)
    if args.by_age is not None and args.estimator != "geometric":
        parser.error("--by-age fits the geometric estimator by age: add --estimator geometric")
    if args.vary != list(RANGED) and (args.ranges != "study" or args.obs_mode != "measurements"):
        parser.error("--vary names the options of --ranges study from measurements")
    if args.by_declared is not None:
        args.by_declared = dict(args.by_declared)
        if args.by_age is None:
            parser.error("--by-declared adds terms to a scale by age: add --by-age")
        if args.hold_to is not None:
            parser.error("--hold-to holds a scale by age alone: drop it with --by-declared")
    if args.hold_to is not None and (args.by_age is None or args.hold_to not in args.by_age[:-1]):
        parser.error("--hold-to must be one of --by-age's knots but the last")
    if args.write and args.observer != "learned":
        parser.error("--write fits the scale of --observer learned only")
    if args.ranges == "study" and args.noise_px is not None:
        parser.error("--noise-px fixes the noise of every episode; --ranges study draws it")
    from observer_gym.train.experiments.consistency_study import FRAME_SYSTEMS

    if args.ranges == "study" and args.obs_mode == "rgb" and args.env not in FRAME_SYSTEMS:
        parser.error(
            "--ranges study with --obs-mode rgb: the study's frames part has "
            f"{', '.join(FRAME_SYSTEMS)} only, not {args.env}"
        )
    print(json.dumps(run(args), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
