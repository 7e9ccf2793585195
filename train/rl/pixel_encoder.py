"""A CNN that reads one camera frame and gives what that frame shows of the state (for
BallTable: the ball's position on the table and the table's tilt; for TargetFollower:
the target's image position and width and whether it is seen), pretrained by
supervised regression on the simulator's ground truth and then frozen.

An agent trained with ``--obs rgb`` and the image option ``encoder`` reads the camera
frames through this network: each frame is resized and made grayscale as usual
(:mod:`observer_gym.train.rl.agent_env`), the encoder maps it to the entries it was trained
on, and the last ``frame_stack`` of those vectors are stacked, so the policy (an MLP)
sees their recent history and can take velocities from it. The encoder is not trained by
the RL algorithm: PPO through a CNN learns millimetre positions too slowly for a
two-core budget (docs/results/ball_table.md, "PPO from pixels over three seeds").

Pretraining: :mod:`observer_gym.train.rl.pretrain_encoder`.

Shipped encoders live in ``observer_gym/train/rl/encoders/<name>.pt`` with a ``<name>.json``
report (the command, the data, the held-out errors); ``encoder: <name>`` picks one, a
path picks any other file.
"""

from __future__ import annotations

import hashlib
import json
import pickle
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from torch import nn

from observer_gym.envs.core import CameraEnv
from observer_gym.estimation.learned.frame_detector import ImageCoordinates

ENCODERS_DIR = Path(__file__).parent / "encoders"


class FrameEncoderNet(nn.Module):
    """(channels, H, W) uint8 frames -> the target entries, in their units.

    Pixel coordinates appended (:class:`ImageCoordinates`), three convolutions (16 8x8
    filters at stride 4, 32 4x4 at stride 2, 32 3x3) and two dense layers (128,
    n_targets): about 2.5 million multiply-adds per 84 x 84 frame. The output is
    de-standardised with the training targets' mean and standard deviation, kept as
    buffers.
    """

    # the buffers registered in __init__ (nn.Module's __getattr__ types them loosely)
    target_mean: torch.Tensor
    target_std: torch.Tensor

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


def encoder_sha256(name: str) -> str:
    """The sha256 of the encoder ``name``'s file (:func:`encoder_path`): a run records it,
    and a trained agent refuses an encoder file that changed since."""
    return hashlib.sha256(encoder_path(name).read_bytes()).hexdigest()


def load_encoder(name: str) -> Encoder:
    """The encoder ``name`` (:func:`encoder_path`), on the CPU. The file is read with
    ``weights_only=True``: tensors and plain data only, so a crafted file runs no code;
    ValueError for a file that holds anything else."""
    path = encoder_path(name)
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        reason = " ".join(str(exc).split())[:200]
        raise ValueError(
            f"encoder file {path} holds more than tensors and plain data; refusing to load "
            f"it ({reason})"
        ) from None
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
        unwrapped = camera_env(env)
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


def camera_env(env: gym.Env) -> CameraEnv:
    """The observer-gym env under ``env``'s wrappers; TypeError for another env."""
    unwrapped = env.unwrapped
    if not isinstance(unwrapped, CameraEnv):
        raise TypeError(f"not an observer-gym camera env: {type(unwrapped).__name__}")
    return unwrapped


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
