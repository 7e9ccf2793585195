"""Fitting a learned observer's network: Gaussian negative log-likelihood on the
simulator's truth, and the held-out report.

    NLL = 1/2 sum_i [ log var_i + (y_i - mean_i)^2 / var_i ]   (per sample, constants dropped)

(``torch.nn.GaussianNLLLoss``), in standardised target units, Adam, minibatches. The
held-out set is whole episodes (the last ``held_out`` fraction), never seen in training:
per-entry RMSE, and NEES/dof = mean over samples of sum_i (y_i - mean_i)^2 / var_i / n
(1 when the predicted variance is the error's). Reproducible from ``seed``: one torch
thread while training, seeded shuffles and initial weights.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, NamedTuple, TypeVar

import numpy as np
import torch
from torch import nn

from observer_gym.estimation.learned.network import GaussianMLP, one_torch_thread

__all__ = ["Dataset", "HeldOut", "fit", "held_out_report", "reproducible", "split"]


class Dataset(NamedTuple):
    """Samples (features, truth) and the episode each came from."""

    features: np.ndarray  # (N, n_in)
    truth: np.ndarray  # (N, n_out)
    episode: np.ndarray  # (N,) int


class HeldOut(NamedTuple):
    rmse: list[float]  # per target entry, in its unit
    nees_per_dof: float
    samples: int


def held_out_report(net: GaussianMLP, data: Dataset) -> HeldOut:
    """The network's per-entry RMSE and NEES/dof on ``data``."""
    with torch.no_grad():
        mean, var = net(torch.as_tensor(data.features, dtype=torch.float64))
    error = mean.numpy() - data.truth
    nees = np.sum(error**2 / var.numpy(), axis=1) / data.truth.shape[1]
    return HeldOut(
        rmse=[float(v) for v in np.sqrt(np.mean(error**2, axis=0))],
        nees_per_dof=float(np.mean(nees)),
        samples=len(data.truth),
    )


EpisodeData = TypeVar("EpisodeData", bound=tuple)


@contextmanager
def reproducible(seed: int) -> Iterator[np.random.Generator]:
    """A fit reproducible from ``seed``: one torch thread (restored after), torch's
    generator seeded; yields NumPy's generator of ``seed`` for the shuffles."""
    with one_torch_thread():
        torch.manual_seed(seed)
        yield np.random.default_rng(seed)


def split(data: EpisodeData, held_out: float) -> tuple[EpisodeData, EpisodeData]:
    """(training, held-out): the last ``held_out`` fraction of the episodes held out, of a
    NamedTuple of per-sample arrays with an ``episode`` field (:class:`Dataset`, the
    learned detector's ``FrameDataset``)."""
    episode = data.episode  # type: ignore[attr-defined]
    episodes = np.unique(episode)
    n_held = max(1, round(held_out * len(episodes)))
    held = np.isin(episode, episodes[-n_held:])
    rebuild = type(data)
    return rebuild(*(a[~held] for a in data)), rebuild(*(a[held] for a in data))


def fit(
    data: Dataset,
    seed: int,
    epochs: int = 60,
    hidden: int = 128,
    batch: int = 256,
    learning_rate: float = 1e-3,
    held_out: float = 0.2,
) -> tuple[GaussianMLP, dict[str, Any]]:
    """Train a :class:`GaussianMLP` on ``data``; (the network, a report: the data's size,
    the held-out errors, the training settings)."""
    train, test = split(data, held_out)
    with reproducible(seed) as rng:
        net = GaussianMLP(data.features.shape[1], data.truth.shape[1], hidden)
        net.set_scaling(train.features, train.truth)
        x = torch.as_tensor(train.features, dtype=torch.float64)
        y = ((torch.as_tensor(train.truth) - net.y_mean) / net.y_std).float()
        loss_fn = nn.GaussianNLLLoss()
        optimiser = torch.optim.Adam(net.parameters(), lr=learning_rate)
        losses = []
        for _ in range(epochs):
            order = rng.permutation(len(y))
            total = 0.0
            for start in range(0, len(y), batch):
                index = torch.as_tensor(order[start : start + batch])
                mean_z, log_var_z = net.standardised(x[index])
                loss = loss_fn(mean_z, y[index], torch.exp(log_var_z))
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
                total += loss.item() * len(index)
            losses.append(total / len(y))
    net.eval()
    net.freeze()
    report = {
        "seed": seed,
        "epochs": epochs,
        "hidden": hidden,
        "batch": batch,
        "learning_rate": learning_rate,
        "train_samples": len(train.truth),
        "train_episodes": len(np.unique(train.episode)),
        "held_out_episodes": len(np.unique(test.episode)),
        "final_train_nll": losses[-1],
        "held_out": held_out_report(net, test)._asdict(),
    }
    return net, report
