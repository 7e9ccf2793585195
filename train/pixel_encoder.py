"""A CNN that reads one camera frame and gives what that frame shows of the state (for
BallTable: the ball's position on the table and the table's tilt), pretrained by
supervised regression on the simulator's ground truth and then frozen.

An agent trained with ``--obs rgb`` and the image option ``encoder`` reads the camera
frames through this network: each frame is resized and made grayscale as usual
(:mod:`observer_gym.train.agent_env`), the encoder maps it to the entries it was trained
on, and the last ``frame_stack`` of those vectors are stacked, so the policy (an MLP)
sees their recent history and can take velocities from it. The encoder is not trained by
the RL algorithm: PPO through a CNN learns millimetre positions too slowly for a
two-core budget (docs/results/ball_table.md, "PPO from pixels over three seeds").

Pretraining (``python -m observer_gym.train.pixel_encoder --env BallTable-v0 ...``):

1. frames: episodes of the agent's rgb env driven by the system's baseline controller on
   the true state (``info["state"]``) plus Ornstein-Uhlenbeck noise whose scale is drawn
   per episode (from none to several times the action range, so both the ball near
   the centre and the ball rolling off are seen), each at most ``episode_steps`` long;
   the target of a frame is the entries :data:`FRAME_TARGETS` of ``info["state"]``;
2. fit: mean squared error on the standardised targets, Adam with a cosine learning-rate
   decay, minibatches of 128, with a tenth of the episodes held out; the report gives the
   held-out RMSE per entry, over all frames and over those with the ball within 3 cm of
   the centre (where a balancing agent keeps it).

Shipped encoders live in ``observer_gym/train/encoders/<name>.pt`` with a ``<name>.json``
report (the command, the data, the held-out errors); ``encoder: <name>`` picks one, a
path picks any other file.
"""

from __future__ import annotations

import importlib
import json
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from torch import nn

ENCODERS_DIR = Path(__file__).parent / "encoders"
BATCH_SIZE = 128
HELD_OUT_FRACTION = 0.1
LEARNING_RATE = 1e-3
NEAR_CENTRE_M = 0.03
# What one frame shows of each system's state (state names), and the controller that
# drives the frames' episodes. BallCatcher's rgb agents read several cameras, which this
# encoder does not take.
FRAME_TARGETS = {"ball_table": ("ball_x_m", "ball_y_m", "tilt_x_rad", "tilt_y_rad")}
COLLECTING_CONTROLLERS = {"ball_table": "lqr"}


class ImageCoordinates(nn.Module):
    """Appends two channels holding each pixel's x and y in [-1, 1] ("CoordConv", Liu et
    al. 2018), so the convolutions' outputs carry where they fired; PyTorch has no such
    layer."""

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        n, _, h, w = images.shape
        ys, xs = torch.meshgrid(
            torch.linspace(-1.0, 1.0, h), torch.linspace(-1.0, 1.0, w), indexing="ij"
        )
        return torch.cat([images, xs.expand(n, 1, h, w), ys.expand(n, 1, h, w)], dim=1)


class FrameEncoderNet(nn.Module):
    """(channels, H, W) uint8 frames -> the target entries, in their units.

    Pixel coordinates appended (:class:`ImageCoordinates`), three convolutions (16 8x8
    filters at stride 4, 32 4x4 at stride 2, 32 3x3) and two dense layers (128,
    n_targets): about 2.5 million multiply-adds per 84 x 84 frame. The output is
    de-standardised with the training targets' mean and standard deviation, kept as
    buffers.
    """

    def __init__(self, channels: int, size_px: int, n_targets: int) -> None:
        super().__init__()
        self.convolutions = nn.Sequential(
            ImageCoordinates(),
            nn.Conv2d(channels + 2, 16, 8, stride=4),
            nn.ReLU(),
            nn.Conv2d(16, 32, 4, stride=2),
            nn.ReLU(),
            nn.Conv2d(32, 32, 3, stride=1),
            nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            flat = self.convolutions(torch.zeros(1, channels, size_px, size_px)).shape[1]
        self.head = nn.Sequential(nn.Linear(flat, 128), nn.ReLU(), nn.Linear(128, n_targets))
        self.register_buffer("target_mean", torch.zeros(n_targets))
        self.register_buffer("target_std", torch.ones(n_targets))

    def standardised(self, frames: torch.Tensor) -> torch.Tensor:
        """The standardised targets of a batch of uint8 frames."""
        return self.head(self.convolutions(frames.float() / 255.0))

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        return self.standardised(frames) * self.target_std + self.target_mean


class Encoder:
    """A pretrained :class:`FrameEncoderNet` with what it was trained on.

    Attributes:
        net: the network (eval mode, no gradients).
        meta: env id, env options, camera and image size, targets, data and held-out
            errors (the ``.json`` report's content).
    """

    def __init__(self, net: FrameEncoderNet, meta: dict[str, Any]) -> None:
        self.net, self.meta = net.eval().requires_grad_(False), meta

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        """The targets (float32) of one (channels, H, W) frame or of a batch of them."""
        batch = np.asarray(frames)
        single = batch.ndim == 3
        with torch.no_grad():
            out = self.net(torch.from_numpy(batch[None] if single else batch)).numpy()
        return out[0] if single else out

    def save(self, path: str | Path) -> None:
        """``path`` (.pt: weights and meta) and its report (.json: meta)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save({"state_dict": self.net.state_dict(), "meta": self.meta}, path)
        path.with_suffix(".json").write_text(json.dumps(self.meta, indent=2) + "\n")


def encoder_path(name: str) -> Path:
    """The file of the encoder ``name``: a shipped one's (``encoders/<name>.pt``), else
    ``name`` as a path. ValueError if neither exists."""
    shipped = ENCODERS_DIR / f"{name}.pt"
    if shipped.is_file():
        return shipped
    path = Path(name)
    if path.is_file():
        return path
    names = sorted(p.stem for p in ENCODERS_DIR.glob("*.pt"))
    raise ValueError(
        f"image encoder {name!r} is neither a shipped encoder ({', '.join(names) or 'none'}) "
        "nor a file"
    )


def load_encoder(name: str) -> Encoder:
    """The encoder ``name`` (:func:`encoder_path`), on the CPU."""
    saved = torch.load(encoder_path(name), map_location="cpu", weights_only=False)
    meta = saved["meta"]
    net = FrameEncoderNet(meta["channels"], meta["image"]["size_px"], len(meta["targets"]))
    net.load_state_dict(saved["state_dict"])
    return Encoder(net, meta)


class EncodedFrames(gym.ObservationWrapper):
    """An rgb agent's env whose (resized, grayscale) frames are replaced by the encoder's
    targets, a float32 vector.

    Raises:
        ValueError: the env is not the system, camera image or preprocessing the encoder
            was trained on.
    """

    def __init__(self, env: gym.Env, encoder: Encoder) -> None:
        super().__init__(env)
        meta = encoder.meta
        unwrapped = env.unwrapped
        size = meta["image"]["size_px"]
        frame = (size, size) if meta["channels"] == 1 else (size, size, 3)
        camera = [unwrapped.config.image_width_px, unwrapped.config.image_height_px]
        env_id = getattr(unwrapped.spec, "id", None)
        if (
            env_id != meta["env_id"]
            or env.observation_space.shape != frame
            or camera != list(meta["camera_px"])
        ):
            raise ValueError(
                f"the image encoder was trained on {meta['env_id']} with camera images "
                f"{meta['camera_px'][0]} x {meta['camera_px'][1]} px resized to frames "
                f"{frame}; this env is {env_id} with {camera[0]} x {camera[1]} px and frames "
                f"{env.observation_space.shape}"
            )
        # One frame at a time in the env's own process: more threads only contend with
        # the other env workers (8 workers x 2 threads slowed training 20-fold).
        torch.set_num_threads(1)
        self.encoder = encoder
        n = len(meta["targets"])
        self.observation_space = spaces.Box(-np.inf, np.inf, (n,), dtype=np.float32)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return self.encoder(channels_first(observation))


def channels_first(frame: np.ndarray) -> np.ndarray:
    """A (H, W) grayscale or (H, W, 3) colour frame as (channels, H, W)."""
    return frame[None] if frame.ndim == 2 else np.ascontiguousarray(frame.transpose(2, 0, 1))


class StackDifferences(gym.ObservationWrapper):
    """A stack of vectors (k, n), oldest first, as (x_t, x_t - x_{t-1}, ...,
    x_{t-k+2} - x_{t-k+1}): the same information, rearranged so that the motion between
    frames is on the scale of its own spread after VecNormalize. In the raw stack a ball's
    1 mm step between frames is 1/40 of the positions' 4 cm spread, and PPO on it did not
    learn to damp the ball (docs/results/ball_table.md)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        shape = env.observation_space.shape
        self.observation_space = spaces.Box(-np.inf, np.inf, shape, dtype=np.float32)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        stack = np.asarray(observation, dtype=np.float32)
        # rows: x_t, then x_t - x_{t-1}, x_{t-1} - x_{t-2}, ... (newest first)
        return np.concatenate([stack[-1:], (stack[1:] - stack[:-1])[::-1]])


# --- pretraining -------------------------------------------------------------------------


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
    from observer_gym.train.agent_env import make_agent_env

    single = {**dict(image), "frame_stack": 1, "encoder": None}
    env = make_agent_env(env_id, "rgb", env_kwargs=env_kwargs, image=single)
    try:
        policy = make_controller(controller, env)
        low = env.unwrapped.action_space.low.astype(np.float64)
        high = env.unwrapped.action_space.high.astype(np.float64)
        rng = np.random.default_rng(seed)
        shape = env.observation_space.shape
        frame_shape = (1, *shape) if len(shape) == 2 else (shape[2], *shape[:2])
        images = np.zeros((frames, *frame_shape), np.uint8)
        states = np.zeros((frames, env.unwrapped.state_space.shape[0]), np.float32)
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
    1 / HELD_OUT_FRACTION are held out), also over the frames where ``near`` is true."""
    torch.manual_seed(seed)
    held_out = episodes % round(1.0 / HELD_OUT_FRACTION) == 0
    mean = targets[~held_out].mean(axis=0)
    std = targets[~held_out].std(axis=0) + 1e-9
    net = FrameEncoderNet(images.shape[1], images.shape[2], targets.shape[1])
    net.target_mean.copy_(torch.from_numpy(mean))
    net.target_std.copy_(torch.from_numpy(std))
    x_train = torch.from_numpy(images[~held_out])
    y_train = torch.from_numpy((targets[~held_out] - mean) / std)
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
            loss = ((net.standardised(x_train[batch]) - y_train[batch]) ** 2).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        schedule.step()
        net.eval()
        with torch.no_grad():
            chunks = [torch.from_numpy(x_test[i : i + 512]) for i in range(0, len(x_test), 512)]
            predicted = np.concatenate([net(chunk).numpy() for chunk in chunks])
        squared = (predicted - y_test) ** 2
        rmse = np.sqrt(squared.mean(axis=0))
        rmse_near = np.sqrt(squared[near_test].mean(axis=0))
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
    file if it exists (collected by an earlier call with the same arguments), else saved
    there."""
    from observer_gym.envs import system_for_id

    system = system_for_id(env_id)
    if system.name not in FRAME_TARGETS:
        allowed = ", ".join(sorted(FRAME_TARGETS))
        raise ValueError(f"no pixel encoder for {system.short_id}; systems with one: {allowed}")
    env_id = system.env_id
    state_names = list(importlib.import_module(f"observer_gym.envs.{system.name}").STATE_NAMES)
    indices = [state_names.index(name) for name in FRAME_TARGETS[system.name]]
    probe = gym.make(env_id, obs_mode="state", **dict(env_kwargs))
    camera_px = [probe.unwrapped.config.image_width_px, probe.unwrapped.config.image_height_px]
    probe.close()
    tic = time.perf_counter()
    data_path = None if data_path is None else Path(data_path)
    if data_path is not None and data_path.is_file():
        with np.load(data_path) as data:
            images, states, episodes = data["frames"], data["states"], data["episodes"]
        if len(images) != frames or images.shape[2] != image["size_px"]:
            raise ValueError(f"{data_path} holds frames {images.shape}, not {frames} of these")
    else:
        controller = COLLECTING_CONTROLLERS[system.name]
        images, states, episodes = collect_frames(
            env_id, frames, seed, image, env_kwargs, controller
        )
        if data_path is not None:
            np.savez(data_path, frames=images, states=states, episodes=episodes)
    collect_s = time.perf_counter() - tic
    tic = time.perf_counter()
    near = np.abs(states[:, :2]).max(axis=1) < NEAR_CENTRE_M
    targets = states[:, indices]
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


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m observer_gym.train.pixel_encoder --env ENV --out FILE.pt``: pretrain an
    encoder on the camera and image options of ``ppo.yml``'s rgb entry for ENV (or
    ``--env-option``) and save it with its report; a mistake is one line on stderr and
    exit code 2."""
    from observer_gym.envs import system_for_id
    from observer_gym.train.cli_args import (
        Parser,
        add_env_option_argument,
        env_name,
        error_line,
        nonnegative_int,
        positive_int,
    )
    from observer_gym.train.hyperparams import resolve_hyperparams

    prog = "python -m observer_gym.train.pixel_encoder"
    parser = Parser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", type=env_name, required=True, help="BallTable-v0")
    parser.add_argument("--out", required=True, help="the encoder file to write (.pt)")
    parser.add_argument("--frames", type=positive_int, default=30_000, help="default: %(default)s")
    parser.add_argument("--epochs", type=positive_int, default=12, help="default: %(default)s")
    parser.add_argument("--seed", type=nonnegative_int, default=0, help="default: %(default)s")
    add_env_option_argument(parser, "a gym.make option over ppo.yml's rgb env_kwargs, repeatable")
    parser.add_argument("--progress", action="store_true", help="print each epoch's errors")
    parser.add_argument(
        "--data",
        metavar="FILE.npz",
        help="read the frames from FILE.npz if it exists, else save them there",
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
    encoder.meta["command"] = " ".join([prog, *(argv if argv is not None else sys.argv[1:])])
    encoder.save(args.out)
    errors = ", ".join(f"{k} {v:.4g}" for k, v in encoder.meta["held_out_rmse"].items())
    print(f"wrote {args.out}: held-out RMSE {errors}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
