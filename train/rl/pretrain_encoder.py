"""Pretraining the frame encoder of rgb agents (:mod:`observer_gym.train.rl.pixel_encoder`):
``python -m observer_gym.train.rl.pretrain_encoder --env BallTable-v0 --out FILE.pt``
(or ``--env TargetFollower-v0``).

1. frames: episodes of the agent's rgb env driven by the system's baseline controller on
   the true state (``info["state"]``) plus Ornstein-Uhlenbeck noise whose scale is drawn
   per episode (from none to several times the action range, so both the ball near
   the centre and the ball rolling off are seen), each at most ``episode_steps`` long;
   the target of a frame is the entries :data:`FRAME_TARGETS` of ``info["state"]``;
   where a frame cannot show some of them (TargetFollower: the target off the image or
   hidden, :data:`SHOWN_ONLY_WHEN`), those are left out of its fit and its errors and
   the flag that says so is a target of its own;
2. fit: mean squared error on the standardised targets, Adam with a cosine learning-rate
   decay, minibatches of 128, with a tenth of the episodes held out; the report gives the
   held-out RMSE per entry, over all frames and over those "near the centre"
   (:data:`NEAR_CENTRE`: where an agent keeps the ball or the target).

It writes FILE.pt (weights and what they were trained on) and FILE.json (the report).
"""

from __future__ import annotations

import importlib
import json
import sys
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from observer_gym.train.rl.pixel_encoder import (
    Encoder,
    FrameEncoderNet,
    camera_env,
    channels_first,
)

BATCH_SIZE = 128
HELD_OUT_FRACTION = 0.1
LEARNING_RATE = 1e-3
NEAR_CENTRE_M = 0.03
# What one frame shows of each system's state (state names), and the controller that
# drives the frames' episodes. BallCatcher's rgb agents read several cameras, which this
# encoder does not take. TargetFollower: the target's image state X_i = (x_i, y_i, d_x)
# and whether it is seen at all.
FRAME_TARGETS = {
    "ball_table": ("ball_x_m", "ball_y_m", "tilt_x_rad", "tilt_y_rad"),
    "target_follower": ("x_i_px", "y_i_px", "d_x_px", "target_visible"),
}
COLLECTING_CONTROLLERS = {"ball_table": "lqr", "target_follower": "vtc"}
# A 0/1 state entry: on frames where it is 0 the frame does not show the system's other
# targets (the target is off the image or fully hidden), so they are left out of the fit
# and of the errors there; the flag itself is fitted on every frame.
SHOWN_ONLY_WHEN = {"target_follower": "target_visible"}
# "near the centre" for the report: both entries within the bound (BallTable: metres;
# TargetFollower: a fraction of the image width, 1/16: 5.25 px of an 84 px image)
NEAR_CENTRE: dict[str, tuple[tuple[str, str], float, bool]] = {
    "ball_table": (("ball_x_m", "ball_y_m"), NEAR_CENTRE_M, False),
    "target_follower": (("x_i_px", "y_i_px"), 1.0 / 16.0, True),
}


def collect_frames(
    env_id: str,
    frames: int,
    seed: int,
    image: Mapping[str, Any],
    env_kwargs: Mapping[str, Any],
    controller: str,
    noise_scales: Sequence[float] = (0.0, 0.1, 0.3, 0.6, 1.5),
    episode_steps: int = 150,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frames (N, channels, H, W) uint8, true states (N, d) float32, episode index (N,))
    from the agent's rgb env (one frame per step) driven by ``controller`` on the true
    state plus Ornstein-Uhlenbeck noise (x <- 0.8 x + 0.6 s w, in [-1, 1] action units,
    s drawn per episode from ``noise_scales``)."""
    from observer_gym.controllers.registry import make_controller
    from observer_gym.train.rl.agent_env import make_agent_env

    single = {**dict(image), "frame_stack": 1, "encoder": None}
    env = make_agent_env(env_id, "rgb", env_kwargs=env_kwargs, image=single)
    try:
        policy = make_controller(controller, env)
        unwrapped = camera_env(env)
        low = unwrapped.action_space.low.astype(np.float64)
        high = unwrapped.action_space.high.astype(np.float64)
        rng = np.random.default_rng(seed)
        shape = env.observation_space.shape
        if shape is None:
            raise ValueError(f"{env_id}'s rgb frames have no shape: {env.observation_space}")
        frame_shape = (1, *shape) if len(shape) == 2 else (shape[2], *shape[:2])
        images = np.zeros((frames, *frame_shape), np.uint8)
        states = np.zeros((frames, unwrapped.state_space.shape[0]), np.float32)
        episodes = np.zeros(frames, np.int64)
        n = episode = 0
        while n < frames:
            observation, info = env.reset(seed=seed * 1_000_003 + episode)
            policy.reset()
            scale = float(rng.choice(noise_scales))
            noise = np.zeros_like(low)
            for _ in range(episode_steps):
                images[n], states[n] = channels_first(observation), info["state"]
                episodes[n] = episode
                n += 1
                if n == frames:
                    break
                action, _ = policy.predict(info["state"][None], deterministic=True)
                action = np.asarray(action, dtype=np.float64).reshape(-1)
                action = 2.0 * (action - low) / (high - low) - 1.0
                noise = 0.8 * noise + 0.6 * scale * rng.standard_normal(noise.shape)
                agent_action = np.clip(action + noise, -1.0, 1.0).astype(np.float32)
                observation, _, terminated, truncated, info = env.step(agent_action)
                if terminated or truncated:
                    break
            episode += 1
        return images, states, episodes
    finally:
        env.close()


def fit_encoder(
    images: np.ndarray,
    targets: np.ndarray,
    episodes: np.ndarray,
    epochs: int,
    seed: int,
    near: np.ndarray | None = None,
    progress: bool = False,
) -> tuple[FrameEncoderNet, dict[str, Any]]:
    """The network fitted to (``images`` -> ``targets``), and its record: the held-out
    RMSE per target after each epoch (episodes whose index is a multiple of
    1 / HELD_OUT_FRACTION are held out), also over the frames where ``near`` is true.
    A NaN target (a frame that does not show it) counts in neither the loss nor the
    errors."""
    torch.manual_seed(seed)
    held_out = episodes % round(1.0 / HELD_OUT_FRACTION) == 0
    mean = np.nanmean(targets[~held_out], axis=0)
    std = np.nanstd(targets[~held_out], axis=0) + 1e-9
    net = FrameEncoderNet(images.shape[1], images.shape[2], targets.shape[1])
    net.target_mean.copy_(torch.from_numpy(mean.astype(np.float32)))
    net.target_std.copy_(torch.from_numpy(std.astype(np.float32)))
    x_train = torch.from_numpy(images[~held_out])
    standardised = ((targets[~held_out] - mean) / std).astype(np.float32)
    shown_train = torch.from_numpy(np.isfinite(standardised))
    y_train = torch.from_numpy(np.nan_to_num(standardised))
    x_test, y_test = images[held_out], targets[held_out]
    near_test = np.ones(len(x_test), bool) if near is None else near[held_out]
    optimiser = torch.optim.Adam(net.parameters(), lr=LEARNING_RATE)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, epochs)
    generator = torch.Generator().manual_seed(seed)
    history = []
    for epoch in range(epochs):
        tic = time.perf_counter()
        net.train()
        order = torch.randperm(len(x_train), generator=generator)
        for start in range(0, len(order), BATCH_SIZE):
            batch = order[start : start + BATCH_SIZE]
            squared = (net.standardised(x_train[batch]) - y_train[batch]) ** 2
            shown = shown_train[batch]
            loss = (squared * shown).sum() / shown.sum().clamp(min=1)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        schedule.step()
        net.eval()
        with torch.no_grad():
            chunks = [torch.from_numpy(x_test[i : i + 512]) for i in range(0, len(x_test), 512)]
            predicted = np.concatenate([net(chunk).numpy() for chunk in chunks])
        squared = (predicted - y_test) ** 2  # NaN where a frame does not show a target
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # nanmean of no frame: NaN
            rmse = np.sqrt(np.nanmean(squared, axis=0))
            rmse_near = (  # NaN when no held-out frame is near
                np.sqrt(np.nanmean(squared[near_test], axis=0))
                if near_test.any()
                else rmse * np.nan
            )
        history.append(
            {
                "epoch": epoch + 1,
                "seconds": time.perf_counter() - tic,
                "rmse": rmse.tolist(),
                "rmse_near": rmse_near.tolist(),
            }
        )
        if progress:
            print(
                f"epoch {epoch + 1}: held-out RMSE {np.round(rmse, 5).tolist()}, near the "
                f"centre {np.round(rmse_near, 5).tolist()}",
                file=sys.stderr,
            )
    return net, {"history": history, "held_out_frames": int(held_out.sum())}


def pretrain(
    env_id: str,
    frames: int,
    epochs: int,
    seed: int,
    image: Mapping[str, Any],
    env_kwargs: Mapping[str, Any],
    progress: bool = False,
    data_path: str | Path | None = None,
) -> Encoder:
    """Collect ``frames`` (:func:`collect_frames`) and fit an encoder of the system's
    :data:`FRAME_TARGETS` to them. With ``data_path`` the frames are read from that .npz
    file if it exists, else saved there with what they were collected with (env, frames,
    seed, image, env options).

    Raises:
        ValueError: ``data_path`` holds frames collected with other arguments.
    """
    from observer_gym.envs import system_for_id

    system = system_for_id(env_id)
    if system.name not in FRAME_TARGETS:
        allowed = ", ".join(sorted(FRAME_TARGETS))
        raise ValueError(f"no pixel encoder for {system.short_id}; systems with one: {allowed}")
    env_id = system.env_id
    state_names = list(importlib.import_module(f"observer_gym.envs.{system.name}").STATE_NAMES)
    indices = [state_names.index(name) for name in FRAME_TARGETS[system.name]]
    probe = gym.make(env_id, obs_mode="state", **dict(env_kwargs))
    try:
        config = camera_env(probe).config
    finally:
        probe.close()
    camera_px = [config.image_width_px, config.image_height_px]
    tic = time.perf_counter()
    data_path = None if data_path is None else Path(data_path)
    collected_with = json.dumps(
        [env_id, frames, seed, dict(image), dict(env_kwargs)], sort_keys=True, default=str
    )
    if data_path is not None and data_path.is_file():
        with np.load(data_path) as data:
            found = str(data["collected_with"]) if "collected_with" in data else None
            if found != collected_with:
                raise ValueError(
                    f"--data {data_path} holds frames collected with (env, frames, seed, "
                    f"image, env options) = {found}, not {collected_with}: name another "
                    "file, or remove it to collect again"
                )
            images, states, episodes = data["frames"], data["states"], data["episodes"]
    else:
        controller = COLLECTING_CONTROLLERS[system.name]
        images, states, episodes = collect_frames(
            env_id, frames, seed, image, env_kwargs, controller
        )
        if data_path is not None:
            np.savez(
                data_path,
                frames=images,
                states=states,
                episodes=episodes,
                collected_with=np.array(collected_with),
            )
    collect_s = time.perf_counter() - tic
    tic = time.perf_counter()
    near_names, near_bound, per_width = NEAR_CENTRE[system.name]
    near_bound *= camera_px[0] if per_width else 1.0
    near_indices = [state_names.index(name) for name in near_names]
    near = np.abs(states[:, near_indices]).max(axis=1) < near_bound
    targets = states[:, indices].astype(np.float32)
    flag = SHOWN_ONLY_WHEN.get(system.name)
    if flag is not None:  # the frame shows the other targets only where the flag is 1
        hidden = states[:, state_names.index(flag)] < 0.5
        others = [k for k, name in enumerate(FRAME_TARGETS[system.name]) if name != flag]
        targets[np.ix_(hidden, others)] = np.nan
    net, record = fit_encoder(images, targets, episodes, epochs, seed, near, progress)
    last = record["history"][-1]
    names = FRAME_TARGETS[system.name]
    meta = {
        "env_id": env_id,
        "env_kwargs": dict(env_kwargs),
        "camera_px": camera_px,
        "image": {k: v for k, v in image.items() if k in ("size_px", "grayscale")},
        "channels": int(images.shape[1]),
        "targets": list(names),
        "controller": COLLECTING_CONTROLLERS[system.name],
        "shown_only_when": flag,
        "near_centre": {"entries": list(near_names), "bound": float(near_bound)},
        "frames": int(frames),
        "episodes": int(episodes[-1] + 1),
        "epochs": int(epochs),
        "seed": int(seed),
        "collect_s": collect_s,
        "fit_s": time.perf_counter() - tic,
        "held_out_rmse": dict(zip(names, last["rmse"], strict=True)),
        "held_out_rmse_near_centre": dict(zip(names, last["rmse_near"], strict=True)),
        **record,
    }
    return Encoder(net, meta)


def _without_option(words: list[str], option: str) -> list[str]:
    """The command line ``words`` without ``option`` and its value (``--opt V`` or
    ``--opt=V``)."""
    kept: list[str] = []
    skip = False
    for word in words:
        if skip:
            skip = False
        elif word == option:
            skip = True
        elif not word.startswith(f"{option}="):
            kept.append(word)
    return kept


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m observer_gym.train.rl.pretrain_encoder --env ENV --out FILE.pt``: pretrain an
    encoder on the camera and image options of ``ppo.yml``'s rgb entry for ENV (or
    ``--env-option``) and save it with its report; a mistake is one line on stderr and
    exit code 2."""
    from observer_gym.envs import system_for_id
    from observer_gym.train.core.args import (
        Parser,
        add_env_option_argument,
        env_name,
        nonnegative_int,
        positive_int,
    )
    from observer_gym.train.core.messages import error_line
    from observer_gym.train.rl.hyperparams import resolve_hyperparams

    prog = "python -m observer_gym.train.rl.pretrain_encoder"
    parser = Parser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--env", type=env_name, required=True, help="BallTable-v0 or TargetFollower-v0"
    )
    parser.add_argument("--out", required=True, help="the encoder file to write (.pt)")
    parser.add_argument("--frames", type=positive_int, default=30_000, help="default: %(default)s")
    parser.add_argument("--epochs", type=positive_int, default=12, help="default: %(default)s")
    parser.add_argument("--seed", type=nonnegative_int, default=0, help="default: %(default)s")
    add_env_option_argument(parser, "a gym.make option over ppo.yml's rgb env_kwargs, repeatable")
    parser.add_argument("--progress", action="store_true", help="print each epoch's errors")
    parser.add_argument(
        "--data",
        metavar="FILE.npz",
        help="read the frames from FILE.npz if it exists (refused if they were collected "
        "with other arguments), else save them there; left out of the recorded command",
    )
    args = parser.parse_args(argv)
    try:
        if not args.out.endswith(".pt"):
            raise ValueError(f"--out must name a .pt file, got {args.out!r}")
        system = system_for_id(args.env)
        params = resolve_hyperparams(system.env_id, "ppo", "rgb")
        env_kwargs = {**params["env_kwargs"], **dict(args.env_option)}
        encoder = pretrain(
            system.env_id,
            args.frames,
            args.epochs,
            args.seed,
            params["image"],
            env_kwargs,
            progress=args.progress,
            data_path=args.data,
        )
    except ValueError as exc:
        print(error_line(prog, exc), file=sys.stderr)
        return 2
    words = list(argv if argv is not None else sys.argv[1:])
    if args.data is not None:  # where the frames were kept does not change the weights
        words = _without_option(words, "--data")
    encoder.meta["command"] = " ".join([prog, *words])
    encoder.save(args.out)
    errors = ", ".join(f"{k} {v:.4g}" for k, v in encoder.meta["held_out_rmse"].items())
    print(f"wrote {args.out}: held-out RMSE {errors}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
