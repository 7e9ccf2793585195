"""A learned detector: a CNN that reads one camera frame and gives what the perfect
detector would report for it, each number with a variance, and each part's probability
of being in view.

It replaces the hand-written image stage in front of a learned observer: from rendered
frames (``obs_mode="rgb"``) the ``learned`` and ``learned-kf`` observers read this
network's output where, from measurements, they read the perfect detector's. Trained
with the Gaussian negative log-likelihood on the perfect detector's pixels of the same
frames (the same episode run in ``obs_mode="measurements"`` beside it: the envs draw
their randomness in the same order in every mode, so both show the same world), so the
variance is part of what it learns.

**Network** (:class:`GaussianFrameNet`): the frame resized (OpenCV, area averaging) to
``width x height`` colour, two pixel-coordinate channels appended ("CoordConv", as the
rgb agents' encoder), four 3 x 3 / 5 x 5 convolutions at stride 2 and a dense layer of
128 (ReLU); three heads: the values' mean and log-variance (standardised with the
training data's mean and std, kept as buffers) and one logit per part (a part's
``detected`` flag). A value is trained only on frames where its part is detected (its
label is undefined otherwise).

A weight file (``.pt``: architecture, camera image size and state dict; read with
``weights_only=True``) has its report beside it (``.json``: command, data, held-out
errors, sha256), and a changed file is refused as every learned observer's is
(:func:`~observer_gym.estimation.learned.network.checked_report`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np
import torch
from torch import nn

from observer_gym.estimation.learned.network import (
    LOG_VAR_RANGE,
    load_weights,
    one_torch_thread,
    save_weights,
)

__all__ = ["Detection", "GaussianFrameNet", "ImageCoordinates", "LearnedDetector", "save_detector"]


class Detection(NamedTuple):
    """One frame through the learned detector."""

    values: np.ndarray  # (n_values,) mean, in pixels
    variance: np.ndarray  # (n_values,) variance, px^2
    detected: np.ndarray  # (n_parts,) bool: the part's probability > 1/2


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


class GaussianFrameNet(nn.Module):
    """(N, 3, height, width) uint8 frames -> (mean, log-variance) of the values in
    standardised units, and the parts' logits (see the module docstring).

    Args:
        width_px, height_px: the network's input size (the frame is resized to it).
        n_values: the numbers per frame (pixel coordinates and sizes).
        value_parts: for each value, the index of the part (``detected`` flag) it
            belongs to.
    """

    y_mean: torch.Tensor
    y_std: torch.Tensor

    def __init__(
        self, width_px: int, height_px: int, n_values: int, value_parts: list[int]
    ) -> None:
        super().__init__()
        if len(value_parts) != n_values:
            raise ValueError(f"value_parts has {len(value_parts)} entries, not {n_values}")
        self.width_px, self.height_px, self.n_values = width_px, height_px, n_values
        self.value_parts = list(value_parts)
        self.n_parts = max(value_parts) + 1
        self.body = nn.Sequential(
            ImageCoordinates(),
            nn.Conv2d(5, 16, 5, stride=2, padding=2),
            nn.ReLU(),
            nn.Conv2d(16, 32, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(32, 32, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(32, 32, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            flat = self.body(torch.zeros(1, 3, height_px, width_px)).shape[1]
        self.dense = nn.Sequential(nn.Linear(flat, 128), nn.ReLU())
        self.mean_head = nn.Linear(128, n_values)
        self.log_var_head = nn.Linear(128, n_values)
        self.part_head = nn.Linear(128, self.n_parts)
        self.register_buffer("y_mean", torch.zeros(n_values))
        self.register_buffer("y_std", torch.ones(n_values))

    def architecture(self) -> dict[str, Any]:
        return {
            "width_px": self.width_px,
            "height_px": self.height_px,
            "n_values": self.n_values,
            "value_parts": self.value_parts,
        }

    def set_scaling(self, values: np.ndarray, detected: np.ndarray) -> None:
        """Standardise each value with its mean and std over the frames where its part
        is detected (std 1 for a constant or never-seen value)."""
        for i, part in enumerate(self.value_parts):
            seen = values[detected[:, part] > 0.5, i]
            std = float(seen.std()) if len(seen) > 1 else 0.0
            self.y_mean[i] = float(seen.mean()) if len(seen) else 0.0
            self.y_std[i] = std if std > 0.0 else 1.0

    def forward(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        h = self.dense(self.body(frames.float() / 255.0))
        log_var = self.log_var_head(h).clamp(*LOG_VAR_RANGE)
        return self.mean_head(h), log_var, self.part_head(h)

    def in_pixels(
        self, mean_z: torch.Tensor, log_var_z: torch.Tensor
    ) -> tuple[np.ndarray, np.ndarray]:
        """(mean, variance) in the values' units (float64) of :meth:`forward`'s
        standardised outputs, for one frame or a batch."""
        y_mean, y_std = self.y_mean.double().numpy(), self.y_std.double().numpy()
        # y = y_mean + y_std z:  E[y] = y_mean + y_std E[z],  Var[y] = y_std^2 Var[z]
        mean = y_mean + y_std * mean_z.double().numpy()
        return mean, y_std**2 * np.exp(log_var_z.double().numpy())


def resized(frame: np.ndarray, width_px: int, height_px: int) -> np.ndarray:
    """An (H, W, 3) uint8 frame as the network reads it: (3, height, width) uint8."""
    small = cv2.resize(frame, (width_px, height_px), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(small.transpose(2, 0, 1))


class SavedFrameNetwork:
    """A trained network that reads a camera's frames, loaded with its report
    (:func:`~observer_gym.estimation.learned.network.load_weights`), and the camera image
    size it was trained on (its pixels' scale: an object's size in them).

    Args:
        path: the weight file; refused if missing or if its sha256 is not its report's.
        network_class: the network's class (built from the file's architecture).
    """

    def __init__(self, path: Path, network_class: type[nn.Module]) -> None:
        net, saved, self.report = load_weights(Path(path), network_class)
        self.net = net.requires_grad_(False)
        self.camera_px: tuple[int, int] = (int(saved["camera_px"][0]), int(saved["camera_px"][1]))

    def outputs(self, x: torch.Tensor) -> Any:
        """The network's outputs for the batch ``x``, without gradients, on one torch
        thread (:func:`~observer_gym.estimation.learned.network.one_torch_thread`)."""
        with one_torch_thread(), torch.no_grad():
            return self.net(x)

    def check_camera(self, image_size_px: tuple[int, int], owner: str) -> None:
        """ValueError unless the env's camera image is the size the network was trained on."""
        if tuple(image_size_px) != self.camera_px:
            raise ValueError(
                f"{owner} reads frames through a network trained on {self.camera_px[0]} x "
                f"{self.camera_px[1]} px camera images; this env's are {image_size_px[0]} x "
                f"{image_size_px[1]} px (set image_width_px and image_height_px to those)"
            )


class LearnedDetector(SavedFrameNetwork):
    """A trained :class:`GaussianFrameNet` and its report, for one frame at a time.

    Args:
        path: the weight file; refused if missing or if its sha256 is not its report's.
    """

    net: GaussianFrameNet

    def __init__(self, path: Path) -> None:
        super().__init__(path, GaussianFrameNet)

    def detect(self, frame: np.ndarray) -> Detection:
        """One (H, W, 3) uint8 frame -> its :class:`Detection`."""
        net = self.net
        x = torch.from_numpy(resized(frame, net.width_px, net.height_px)[None])
        mean_z, log_var_z, logits = self.outputs(x)
        values, variance = net.in_pixels(mean_z[0], log_var_z[0])
        return Detection(values, variance, logits[0].numpy() > 0.0)


def save_detector(
    net: GaussianFrameNet, camera_px: tuple[int, int], path: Path, report: dict[str, Any]
) -> None:
    """Write ``path`` (.pt) and its report (.json, with the file's sha256)."""
    saved = {
        "architecture": net.architecture(),
        "camera_px": list(camera_px),
        "state_dict": net.state_dict(),
    }
    save_weights(path, saved, report)
