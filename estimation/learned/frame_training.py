"""Fitting a learned detector (:mod:`~observer_gym.estimation.learned.frame_detector`)
on frames and the perfect detector's pixels of the same frames, and its held-out report.

Per frame, with m_i = 1 when value i's part is detected (its label exists):

    NLL_i = 1/2 [ log var_i + (y_i - mean_i)^2 / var_i ]
    loss = sum_i m_i sg(var_i)^beta NLL_i / max(1, sum_i m_i) + BCE(part logits, detected)

in standardised value units, with beta = :data:`BETA` ("beta-NLL", Seitzer et al. 2022;
sg: no gradient through that factor). Plain NLL (beta 0) scales each mean's gradient by
1 / var_i, so a value the network finds hard early gets a large variance and then hardly
any gradient: on BallTable it left the ball's centre at 5.3 and 5.9 px held out while
the corners reached 0.04-0.08 px (12 epochs). Adam with a cosine learning-rate decay,
minibatches of :data:`BATCH`. Held out: the last ``held_out`` fraction of the episodes
(whole episodes, never seen in training): per-value RMSE and NEES/dof over the frames
where the part is detected, and the fraction of parts whose detected flag is right.
Reproducible from ``seed``: one torch thread, seeded shuffles and initial weights.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn

from observer_gym.estimation.learned.frame_detector import GaussianFrameNet
from observer_gym.estimation.learned.training import reproducible, split

__all__ = ["FrameDataset", "detector_report", "fit_detector", "train_minibatches"]

BATCH = 64
LEARNING_RATE = 1e-3
BETA = 0.5


class FrameDataset(NamedTuple):
    """Frames (as the network reads them) with the perfect detector's report of each."""

    frames: np.ndarray  # (N, 3, height, width) uint8
    values: np.ndarray  # (N, n_values) float, px
    detected: np.ndarray  # (N, n_parts) 0/1
    episode: np.ndarray  # (N,) int


def detector_report(net: GaussianFrameNet, data: FrameDataset) -> dict[str, Any]:
    """Per-value RMSE (px) and NEES/dof over the detected frames, and the fraction of
    detected flags the network gets right, on ``data``."""
    means, variances, logits = [], [], []
    with torch.no_grad():
        for start in range(0, len(data.frames), 256):
            mean_z, log_var_z, logit = net(torch.from_numpy(data.frames[start : start + 256]))
            batch_mean, batch_var = net.in_pixels(mean_z, log_var_z)
            means.append(batch_mean)
            variances.append(batch_var)
            logits.append(logit.numpy())
    mean, var = np.concatenate(means), np.concatenate(variances)
    seen = data.detected[:, net.value_parts] > 0.5  # (N, n_values)
    error = np.where(seen, mean - data.values, 0.0)
    counts = np.maximum(seen.sum(axis=0), 1)
    rmse = np.sqrt((error**2).sum(axis=0) / counts)
    nees = (error**2 / var)[seen].mean()
    right = (np.concatenate(logits) > 0.0) == (data.detected > 0.5)
    return {
        "frames": len(data.frames),
        "rmse_px": [round(float(v), 4) for v in rmse],
        "nees_per_dof": round(float(nees), 4),
        "detected_right": [round(float(v), 4) for v in right.mean(axis=0)],
    }


def train_minibatches(
    net: nn.Module,
    samples: int,
    batch_loss: Callable[[torch.Tensor], torch.Tensor],
    epochs: int,
    rng: np.random.Generator,
) -> list[float]:
    """Adam with a cosine learning-rate decay over ``epochs`` passes of shuffled
    minibatches of :data:`BATCH` (``batch_loss(indices)``: the minibatch's mean loss);
    each epoch's mean loss (4 decimals). The network is left in eval mode. The learned
    detectors' loop (this module's, and the heat-map detector's)."""
    optimiser = torch.optim.Adam(net.parameters(), lr=LEARNING_RATE)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, epochs * -(-samples // BATCH))
    losses = []
    for _ in range(epochs):
        net.train()
        order = rng.permutation(samples)
        total = 0.0
        for start in range(0, samples, BATCH):
            index = torch.as_tensor(order[start : start + BATCH])
            loss = batch_loss(index)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            total += loss.item() * len(index)
        losses.append(round(total / samples, 4))
    net.eval()
    return losses


def fit_detector(
    data: FrameDataset,
    value_parts: list[int],
    seed: int,
    epochs: int,
    held_out: float = 0.2,
) -> tuple[GaussianFrameNet, dict[str, Any]]:
    """Train a :class:`GaussianFrameNet` on ``data`` (input size from the frames' shape,
    ``value_parts`` the part of each value); (the network, a report: data size, settings,
    per-epoch training loss, held-out errors)."""
    train, test = split(data, held_out)
    with reproducible(seed) as rng:
        _, _, height, width = data.frames.shape
        net = GaussianFrameNet(width, height, data.values.shape[1], value_parts)
        net.set_scaling(train.values, train.detected)
        frames = torch.from_numpy(train.frames)
        y = ((torch.as_tensor(train.values).float() - net.y_mean) / net.y_std).nan_to_num()
        mask = torch.as_tensor(train.detected[:, value_parts] > 0.5).float()
        flags = torch.as_tensor(train.detected).float()
        bce = nn.BCEWithLogitsLoss()

        def batch_loss(index: torch.Tensor) -> torch.Tensor:
            mean_z, log_var_z, logits = net(frames[index])
            m = mask[index]
            # NLL_i = 1/2 [log var_i + (y_i - mean_i)^2 / var_i]
            nll = 0.5 * (log_var_z + (y[index] - mean_z) ** 2 / torch.exp(log_var_z))
            # sum_i m_i sg(var_i)^beta NLL_i / sum_i m_i
            weight = m * torch.exp(BETA * log_var_z).detach()
            loss = (weight * nll).sum(dim=1) / m.sum(dim=1).clamp(min=1.0)
            return loss.mean() + bce(logits, flags[index])

        losses = train_minibatches(net, len(y), batch_loss, epochs, rng)
    report = {
        "seed": seed,
        "epochs": epochs,
        "batch": BATCH,
        "learning_rate": LEARNING_RATE,
        "beta": BETA,
        "train_frames": len(train.frames),
        "train_episodes": len(np.unique(train.episode)),
        "held_out_episodes": len(np.unique(test.episode)),
        "train_loss": losses,
        "held_out": detector_report(net, test),
    }
    return net, report
