"""The Gaussian network of a learned observer, and its weight files.

:class:`GaussianMLP` maps a feature vector to a mean and a diagonal covariance of the
state (per entry a log-variance head): trained with the Gaussian negative log-likelihood,
its variance is part of what it learns. Inputs and targets are standardised with the
training data's mean and standard deviation, kept as buffers, so the weight file is the
whole model.

A weight file (``<name>.pt``: ``torch.save`` of the state dict and the architecture,
read back with ``weights_only=True``, which unpickles no code) has a report beside it
(``<name>.json``: the command that trained it, the data, the held-out errors, and the
file's sha256). :func:`load_network` refuses a weight file whose sha256 is not the
report's, in one line naming both.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import torch
from torch import nn

from observer_gym.envs.json_file import read_json

__all__ = [
    "GaussianMLP",
    "checked_report",
    "file_sha256",
    "load_network",
    "load_weights",
    "one_torch_thread",
    "save_network",
    "save_weights",
]

# log-variance heads are clamped to this range (standardised units): exp(-14) ~ 1e-6 of
# the target's spread, exp(6) ~ 400 times; keeps the NLL finite early in training
LOG_VAR_RANGE = (-14.0, 6.0)


class GaussianMLP(nn.Module):
    """features (n_in,) -> mean (n_out,), variance (n_out,), in the targets' units.

    Two hidden layers of ``hidden`` units (tanh), a mean head and a log-variance head.
    """

    # standardisation of the inputs and the targets (buffers, saved with the weights)
    x_mean: torch.Tensor
    x_std: torch.Tensor
    y_mean: torch.Tensor
    y_std: torch.Tensor

    def __init__(self, n_in: int, n_out: int, hidden: int = 128) -> None:
        super().__init__()
        self.n_in, self.n_out, self.hidden = n_in, n_out, hidden
        self.body = nn.Sequential(
            nn.Linear(n_in, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh()
        )
        self.mean_head = nn.Linear(hidden, n_out)
        self.log_var_head = nn.Linear(hidden, n_out)
        for name, size in (("x_mean", n_in), ("y_mean", n_out)):
            self.register_buffer(name, torch.zeros(size, dtype=torch.float64))
        for name, size in (("x_std", n_in), ("y_std", n_out)):
            self.register_buffer(name, torch.ones(size, dtype=torch.float64))
        self._frozen: dict[str, np.ndarray] | None = None

    def set_scaling(self, x: np.ndarray, y: np.ndarray) -> None:
        """Standardise with the training data's mean and std (a constant column: std 1)."""
        for name, data in (("x", x), ("y", y)):
            mean, std = data.mean(axis=0), data.std(axis=0)
            std = np.where(std > 0.0, std, 1.0)
            getattr(self, f"{name}_mean").copy_(torch.as_tensor(mean))
            getattr(self, f"{name}_std").copy_(torch.as_tensor(std))

    def standardised(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, log-variance) in standardised target units, for the loss."""
        h = self.body(((x - self.x_mean) / self.x_std).float())
        return self.mean_head(h), self.log_var_head(h).clamp(*LOG_VAR_RANGE)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, variance) in the targets' units (float64)."""
        mean_z, log_var_z = self.standardised(x)
        # y = y_mean + y_std z:  E[y] = y_mean + y_std E[z],  Var[y] = y_std^2 Var[z]
        mean = self.y_mean + self.y_std * mean_z.double()
        variance = self.y_std**2 * torch.exp(log_var_z.double())
        return mean, variance

    def predict(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One feature vector (n_in,) -> (mean (n_out,), covariance (n_out, n_out)).

        The same arithmetic as :meth:`forward` in NumPy (float64), on weights copied once
        (:meth:`freeze`): one sample through torch costs ~100 us of call overhead and
        wakes its thread pool every step; this costs ~20 us."""
        w = self._frozen if self._frozen is not None else self.freeze()
        h = np.tanh(w["W1"] @ ((features - w["x_mean"]) / w["x_std"]) + w["b1"])
        h = np.tanh(w["W2"] @ h + w["b2"])
        log_var_z = np.clip(w["Wv"] @ h + w["bv"], *LOG_VAR_RANGE)
        mean = w["y_mean"] + w["y_std"] * (w["Wm"] @ h + w["bm"])
        return mean, np.diag(w["y_std"] ** 2 * np.exp(log_var_z))

    def freeze(self) -> dict[str, np.ndarray]:
        """The weights as float64 arrays for :meth:`predict` (call again after training)."""
        first, second = (m for m in self.body if isinstance(m, nn.Linear))
        layers = {"1": first, "2": second, "m": self.mean_head, "v": self.log_var_head}
        w = {f"W{k}": m.weight.detach().double().numpy().copy() for k, m in layers.items()}
        w |= {f"b{k}": m.bias.detach().double().numpy().copy() for k, m in layers.items()}
        buffers = {"x_mean": self.x_mean, "x_std": self.x_std}
        buffers |= {"y_mean": self.y_mean, "y_std": self.y_std}
        for name, buffer in buffers.items():
            w[name] = buffer.detach().numpy().copy()
        self._frozen = w
        return w


@contextmanager
def one_torch_thread() -> Iterator[None]:
    """Torch on one thread inside, its thread count restored after. For a fit, so that it
    is reproducible; for one frame's inference, too small to share, and on a shared
    machine torch's threads wait for each other: with three busy processes beside it,
    torch's default two threads took 272 ms a BallTable frame against 1.1 ms on one; idle,
    1.1 against 1.0 (``python benchmarks/bench_learned_detector_threads.py --busy 3``,
    one run, 2026-11-26; the size of the effect depends on the load: 1.1x with 4 busy)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def save_weights(path: Path, saved: dict[str, Any], report: dict[str, Any]) -> None:
    """Write ``saved`` (its ``architecture``, ``state_dict`` and any other plain data) to
    ``path`` (.pt) and ``report`` beside it (.json, with the architecture and the file's
    sha256, which :func:`checked_report` checks)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(saved, path)
    report = {**report, "architecture": saved["architecture"], "sha256": file_sha256(path)}
    path.with_suffix(".json").write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")


def save_network(net: GaussianMLP, path: Path, report: dict[str, Any]) -> None:
    """Write ``path`` (.pt) and its report (.json, with the file's sha256)."""
    architecture = {"n_in": net.n_in, "n_out": net.n_out, "hidden": net.hidden}
    save_weights(path, {"architecture": architecture, "state_dict": net.state_dict()}, report)


def checked_report(path: Path) -> dict[str, Any]:
    """The report beside the weight file ``path``, once the file's sha256 is the report's.

    Raises:
        ValueError: no weight file or report there, or the file's sha256 is not the
            report's (a changed or other file).
    """
    report_path = path.with_suffix(".json")
    if not path.is_file() or not report_path.is_file():
        raise ValueError(
            f"learned observer weights {path} (and their report {report_path.name}) not "
            "found; train them with python -m "
            "observer_gym.train.experiments.learned_observers.train"
        )
    report = read_json(report_path, allow_nan=True)  # JSONFileError (a ValueError) names it
    if not isinstance(report, dict):
        raise ValueError(
            f"{report_path} is not the report of learned observer weights (a JSON object)"
        )
    found = file_sha256(path)
    if found != report.get("sha256"):
        raise ValueError(
            f"learned observer weights {path} have sha256 {found[:12]}..., their report "
            f"{report_path.name} says {str(report.get('sha256'))[:12]}...: a changed file "
            "is refused; train it again or restore the shipped file"
        )
    return report


Network = TypeVar("Network", bound=nn.Module)


def load_weights(
    path: Path, network_class: type[Network]
) -> tuple[Network, dict[str, Any], dict[str, Any]]:
    """The ``network_class`` written to ``path`` by :func:`save_weights` (in evaluation
    mode), everything the file holds, and its report, once the file's sha256 is the
    report's.

    Raises:
        ValueError: no weight file or report there, the file's sha256 is not the
            report's (a changed or other file), or a file that is not such weights (a
            damaged file, no architecture, tensors of other shapes), naming the file.
    """
    path = Path(path)
    report = checked_report(path)
    try:  # tensors and plain data only (weights_only); anything else is refused
        saved = torch.load(path, weights_only=True)
        net = network_class(**saved["architecture"])
        net.load_state_dict(saved["state_dict"])
    except Exception as exc:  # a damaged zip, no architecture, other shapes: any of them
        reason = " ".join(str(exc).split())[:300]
        raise ValueError(
            f"learned observer weights {path} cannot be loaded as a {network_class.__name__}: "
            f"{type(exc).__name__}: {reason}; train them again or restore the shipped file"
        ) from None
    net.eval()
    return net, saved, report


def load_network(path: Path) -> tuple[GaussianMLP, dict[str, Any]]:
    """The network in ``path`` and its report, in evaluation mode (see
    :func:`load_weights`)."""
    net, _, report = load_weights(path, GaussianMLP)
    net.freeze()
    return net, report
