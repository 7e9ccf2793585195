"""The rgb detector's error model: how far its (x_i, y_i, d_x) lies from the truth on
rendered frames, measured once per image-noise level and stored with the command that
measured it (``detector_error.json`` beside this module).

The measurement: TargetFollower-v0 in ``obs_mode="rgb"`` at each ``image_noise_std`` of
:data:`NOISE_LEVELS`, episodes from seeded resets (the env's random target starts, 1.1-1.7
m ahead) with the robot driven by small random actions (so the target takes every place
and sub-pixel phase on the image); every frame whose target lies wholly on the image and
is not hidden is detected, and the error against the simulator's image state recorded.
Frames with a partly cut or partly hidden target are not in the model: their error is
the missing part's (up to half the width), and the detector refuses such a blob
(:class:`~observer_gym.estimation.target_follower.detector.TargetFollowerDetector`).

The stored model, per level: the mean and the root mean square of each coordinate's
error divided by the target's width d_x. Every error grows with the target's size (the
centroid of a larger disc moves by more whole pixels at its rim), so the model is
relative:

    b_j(image_noise_std, d_x) = mean_j(image_noise_std) d_x          (the bias)
    s_j(image_noise_std, d_x)^2 = (rms_j^2 - mean_j^2) d_x^2          (the scatter about it)

interpolated linearly between the measured levels (and held beyond the last). With image
noise the error is mostly the bias (at 32: d_x -8.9 %, its RMS 8.9 %): the blob loses
its rim pixels to the noise.
:func:`load_detector_error` reads the stored file. To measure it again::

    python -m observer_gym.estimation.target_follower.detector_error --frames 800 --seed 0

(a minute or two on one core).
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from observer_gym.envs.json_file import read_json

__all__ = ["DetectorErrorModel", "load_detector_error", "measure_detector_error"]

ENV_ID = "observer_gym/TargetFollower-v0"
DEFAULT_PATH = Path(__file__).with_name("detector_error.json")
# image_noise_std levels (0-255 intensities): the config's range, 0 to 64
NOISE_LEVELS = (0.0, 8.0, 16.0, 24.0, 32.0, 48.0, 64.0)
ACTION_SCALE = 0.3  # the random actions' bound on (v, omega, omega_t)
STEPS_PER_EPISODE = 20
MARGIN_PX = 1.0  # the target's disc must lie this far inside the image


@dataclass(frozen=True)
class DetectorErrorModel:
    """The detector's error per coordinate relative to the width d_x, at each measured
    ``image_noise_std`` (see the module docstring)."""

    noise_levels: tuple[float, ...]
    rms_over_width: tuple[tuple[float, float, float], ...]  # per level: (x_i, y_i, d_x)
    mean_over_width: tuple[tuple[float, float, float], ...]  # per level: (x_i, y_i, d_x)

    def __post_init__(self) -> None:
        levels = np.asarray(self.noise_levels, dtype=float)
        if levels.ndim != 1 or len(levels) == 0 or np.any(np.diff(levels) <= 0.0):
            raise ValueError(f"noise_levels = {self.noise_levels!r}: increasing, at least one")
        rms = np.asarray(self.rms_over_width, dtype=float)
        mean = np.asarray(self.mean_over_width, dtype=float)
        if rms.shape != (len(levels), 3) or not np.all(np.isfinite(rms)) or np.any(rms < 0.0):
            raise ValueError(
                f"rms_over_width must be {len(levels)} finite triples >= 0, got {rms.tolist()}"
            )
        if mean.shape != rms.shape or not np.all(np.abs(mean) <= rms + 1e-12):
            raise ValueError(
                f"mean_over_width must be {len(levels)} triples within rms_over_width, got "
                f"{mean.tolist()}"
            )

    def _at(self, table, image_noise_std: float) -> np.ndarray:
        values = np.asarray(table, dtype=float)
        return np.array(
            [np.interp(image_noise_std, self.noise_levels, values[:, j]) for j in range(3)]
        )

    def relative_bias(self, image_noise_std: float) -> np.ndarray:
        """mean_j / d_x (3,) at ``image_noise_std``, linear between the measured levels."""
        return self._at(self.mean_over_width, image_noise_std)

    def relative_scatter(self, image_noise_std: float) -> np.ndarray:
        """sqrt(rms_j^2 - mean_j^2) / d_x (3,) at ``image_noise_std``."""
        rms = self._at(self.rms_over_width, image_noise_std)
        return np.sqrt(np.maximum(rms**2 - self.relative_bias(image_noise_std) ** 2, 0.0))


def _triple(values: list, what: str) -> tuple[float, float, float]:
    """(x_i, y_i, d_x) of a stored level's entry ``what``; ValueError unless 3 numbers."""
    if len(values) != 3:
        raise ValueError(f"{what} must be a triple (x_i, y_i, d_x), got {values!r}")
    x_i, y_i, d_x = (float(v) for v in values)
    return x_i, y_i, d_x


@lru_cache(maxsize=4)
def load_detector_error(path: str | Path = DEFAULT_PATH) -> DetectorErrorModel:
    """The stored model (``detector_error.json`` by default)."""
    data = read_json(path, allow_nan=True)
    levels = data["levels"]
    return DetectorErrorModel(
        tuple(float(level["image_noise_std"]) for level in levels),
        tuple(_triple(level["rms_over_width"], "rms_over_width") for level in levels),
        tuple(_triple(level["mean_over_width"], "mean_over_width") for level in levels),
    )


def _errors_at(image_noise_std: float, frames: int, seed: int) -> dict:
    """Detection errors on ``frames`` rendered frames at one noise level."""
    import gymnasium as gym

    import observer_gym.envs  # noqa: F401  (registers the envs)
    from observer_gym.envs.target_follower import IMAGE, StateIndex, TargetFollowerEnv
    from observer_gym.estimation.target_follower.detector import TargetFollowerDetector

    env = gym.make(ENV_ID, obs_mode="rgb", image_noise_std=float(image_noise_std))
    detector = TargetFollowerDetector()
    rng = np.random.default_rng(seed)
    target_follower = env.unwrapped
    if not isinstance(target_follower, TargetFollowerEnv):
        raise TypeError(f"{ENV_ID} made a {type(target_follower).__name__}")
    half_w, half_h = (0.5 * s for s in target_follower.rig.image_size_px)
    errors: list[np.ndarray] = []  # detection - truth, (3,) each
    widths: list[float] = []  # the true d_x of each
    missed, episode = 0, 0
    try:
        while len(errors) + missed < frames:
            obs, info = env.reset(seed=seed + episode)
            episode += 1
            for _ in range(STEPS_PER_EPISODE):
                x_i, y_i, d_x = info["state"][IMAGE]
                radius = 0.5 * d_x + MARGIN_PX
                whole = abs(x_i) + radius < half_w and abs(y_i) + radius < half_h
                if info["frames"] and whole and info["state"][StateIndex.TARGET_VISIBLE]:
                    z = detector.detect(obs, info["frames"][0]["K"])
                    if z is None:
                        missed += 1
                    else:
                        errors.append(z - info["state"][IMAGE])
                        widths.append(d_x)
                action = rng.uniform(-ACTION_SCALE, ACTION_SCALE, 3).astype(np.float32)
                obs, _, terminated, truncated, info = env.step(action)
                if terminated or truncated:
                    break
    finally:
        env.close()
    e, w = np.array(errors), np.array(widths)
    return {
        "image_noise_std": float(image_noise_std),
        "frames": len(e),
        "missed": int(missed),
        "width_px_range": [float(w.min()), float(w.max())],
        "rms_over_width": np.sqrt(np.mean((e / w[:, None]) ** 2, axis=0)).tolist(),
        "mean_over_width": np.mean(e / w[:, None], axis=0).tolist(),
        "rms_px": np.sqrt(np.mean(e**2, axis=0)).tolist(),
        "max_abs_px": np.abs(e).max(axis=0).tolist(),
    }


def measure_detector_error(frames: int, seed: int, levels=NOISE_LEVELS) -> dict:
    """The model's record: per level, the errors of ``frames`` detections (see the module
    docstring)."""
    return {
        "what": "TargetFollower detector error on rendered frames, relative to the width d_x",
        "command": (
            "python -m observer_gym.estimation.target_follower.detector_error "
            f"--frames {frames} --seed {seed}"
        ),
        "seed": seed,
        "frames_per_level": frames,
        "date": datetime.date.today().isoformat(),
        "levels": [_errors_at(level, frames, seed) for level in levels],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m observer_gym.estimation.target_follower.detector_error",
        description="Measure the TargetFollower detector's error model on rendered frames.",
    )
    parser.add_argument("--frames", type=int, default=800, help="frames per noise level")
    parser.add_argument("--seed", type=int, default=0, help="first episode seed")
    parser.add_argument("--out", type=Path, default=DEFAULT_PATH, help="the JSON file to write")
    args = parser.parse_args(argv)
    if args.frames < 10:
        parser.error(f"--frames {args.frames}: at least 10")
    if args.seed < 0:
        parser.error(f"--seed {args.seed}: must be >= 0")
    record = measure_detector_error(args.frames, args.seed)
    args.out.write_text(json.dumps(record, indent=1) + "\n")
    for level in record["levels"]:
        rms = ", ".join(f"{v:.4f}" for v in level["rms_over_width"])
        mean = ", ".join(f"{v:.4f}" for v in level["mean_over_width"])
        print(
            f"image_noise_std {level['image_noise_std']:g}: {level['frames']} frames, "
            f"{level['missed']} missed, rms / d_x ({rms}), mean / d_x ({mean})"
        )
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
