"""A learned point detector for small objects: a fully convolutional network that reads a
camera frame at its full resolution and gives where one point (a ball's centre) is, in
pixels with a variance, and its probability of being in the image.

It is the learned detector of a system whose object is too small for the resize to 128 x
96 of :mod:`~observer_gym.estimation.learned.frame_detector` (BallCatcher's ball, 4-12 px
across at 320 x 240, would be 2-5 px there). Like that one, it is trained on the perfect
detector's pixels of the same frames (lockstep episodes,
:func:`~observer_gym.train.experiments.learned_observers.frame_data.collect_lockstep`),
and a weight file has its report beside it and is refused if changed
(:func:`~observer_gym.estimation.learned.network.checked_report`).

**Network** (:class:`PointHeatmapNet`, CenterNet-style, Zhou et al. 2019): two
convolutions at stride 2 (5 x 5, then 3 x 3) and two 3 x 3 at stride 1, ReLU, and a 1 x 1
head giving per cell of the stride-:data:`STRIDE_PX` grid five numbers: the logit of "the
point is nearest this cell's anchor" (the anchor of cell (i, j) is pixel (u, v) =
(4 j, 4 i)), the point's offset (u, v) from the anchor (px / 4) and the log-variance
(px^2) of each. Its receptive field is 27 px, so it reads the object and its
surroundings but not where in the image they are: it is trained on crops
(:data:`~observer_gym.estimation.learned.frame_training.FrameDataset` frames of any
size divisible by 4) and runs on the whole frame (translation-equivariant: no
coordinate channels).

**Output** (:meth:`PointHeatmapNet.decode`): the cell of the largest logit; the point's
probability is its sigmoid (detected above 1/2), its (u, v) the anchor plus the offset
there and its variance that cell's.

**Loss** (per crop, summed over the cells, then the batch's mean):

    heat = sum_cells BCE(logit, [cell is the point's]) over all cells but the point's 8
           neighbours (a point near a cell's border may look like either's)
    offset = mean over the point's cell and its 8 neighbours of
             sum_(u,v) sg(var)^beta 1/2 [log var + (y - mean)^2 / var]

(beta-NLL, beta = :data:`~observer_gym.estimation.learned.frame_training.BETA`: every
cell of the 3 x 3 learns the offset, so :meth:`~PointHeatmapNet.decode` may pick any).
Adam with a cosine learning-rate decay, minibatches of
:data:`~observer_gym.estimation.learned.frame_training.BATCH`, reproducible from the seed
(:func:`~observer_gym.estimation.learned.training.reproducible`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from observer_gym.estimation.learned.frame_detector import SavedFrameNetwork
from observer_gym.estimation.learned.frame_training import (
    BATCH,
    BETA,
    LEARNING_RATE,
    FrameDataset,
    train_minibatches,
)
from observer_gym.estimation.learned.network import save_weights
from observer_gym.estimation.learned.training import reproducible, split

__all__ = [
    "STRIDE_PX",
    "LearnedPointDetector",
    "PointDetection",
    "PointHeatmapNet",
    "fit_point_detector",
    "point_report",
    "save_point_detector",
]

STRIDE_PX = 4  # the output grid's cell (px)
# the log-variance head (log px^2) is clamped to this: 0.05 px to 20 px std
LOG_VAR_RANGE_PX2 = (-6.0, 6.0)
# the heat map's initial probability per cell (CenterNet's prior, as in focal-loss
# detectors): with 1/2 the first batches' loss is ~180 per crop, all of it on empty cells
INITIAL_PROBABILITY = 0.01


class PointDetection(NamedTuple):
    """One frame through the learned point detector."""

    uv_px: np.ndarray  # (2,) the point's (u, v), px
    variance_px2: np.ndarray  # (2,) the variance of u and of v, px^2
    probability: float  # that the point is in the image
    detected: bool  # probability > 1/2


class PointHeatmapNet(nn.Module):
    """(N, 3, H, W) uint8 images (H, W divisible by :data:`STRIDE_PX`) -> (N, 5, H / 4,
    W / 4): per cell the logit, the offset (u, v) / 4 and the log-variance (u, v)
    (module docstring).

    Args:
        channels: the width of the convolutions after the first (which has half).
    """

    def __init__(self, channels: int = 32) -> None:
        super().__init__()
        if int(channels) != channels or channels < 2:
            raise ValueError(f"PointHeatmapNet: channels = {channels!r}, must be an int >= 2")
        self.channels = int(channels)
        half = self.channels // 2
        self.body = nn.Sequential(
            nn.Conv2d(3, half, 5, stride=2, padding=2),
            nn.ReLU(),
            nn.Conv2d(half, self.channels, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(self.channels, self.channels, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(self.channels, self.channels, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(self.channels, 5, 1),
        )
        with torch.no_grad():  # start each cell's probability at INITIAL_PROBABILITY
            head = self.body[-1]
            assert isinstance(head, nn.Conv2d) and head.bias is not None
            head.bias[0] = -math.log((1.0 - INITIAL_PROBABILITY) / INITIAL_PROBABILITY)

    def architecture(self) -> dict[str, Any]:
        return {"channels": self.channels}

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.body(images.float() / 255.0)

    @staticmethod
    def anchors_px(height_cells: int, width_cells: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(u, v) anchors of the cells, each (height_cells, width_cells), px."""
        v, u = torch.meshgrid(
            torch.arange(height_cells, dtype=torch.float32) * STRIDE_PX,
            torch.arange(width_cells, dtype=torch.float32) * STRIDE_PX,
            indexing="ij",
        )
        return u, v

    @staticmethod
    def decode(out: torch.Tensor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`forward`'s output (N, 5, h, w) -> (uv_px (N, 2), variance_px2 (N, 2),
        probability (N,)) at each image's most likely cell (float64)."""
        n, w = out.shape[0], out.shape[3]
        best = out[:, 0].reshape(n, -1).argmax(dim=1)
        i, j = best // w, best % w
        cell = out[torch.arange(n), :, i, j].double()  # (N, 5)
        anchor = torch.stack([j, i], dim=1).double() * STRIDE_PX
        uv = anchor + STRIDE_PX * cell[:, 1:3]
        variance = torch.exp(cell[:, 3:5].clamp(*LOG_VAR_RANGE_PX2))
        probability = torch.sigmoid(cell[:, 0])
        return uv.numpy(), variance.numpy(), probability.numpy()


def _loss(net_out: torch.Tensor, uv_px: torch.Tensor, detected: torch.Tensor) -> torch.Tensor:
    """The batch's loss (module docstring): ``net_out`` (B, 5, h, w), ``uv_px`` (B, 2) the
    point in each image (any value where not detected), ``detected`` (B,) bool."""
    h, w = net_out.shape[2:]
    logits = net_out[:, 0]
    # the point's cell: nearest anchor, kept on the grid
    j = torch.round(uv_px[:, 0] / STRIDE_PX).long().clamp(0, w - 1)
    i = torch.round(uv_px[:, 1] / STRIDE_PX).long().clamp(0, h - 1)
    target = torch.zeros_like(logits)
    weight = torch.ones_like(logits)
    rows = torch.nonzero(detected).flatten()
    di, dj = torch.meshgrid(torch.arange(-1, 2), torch.arange(-1, 2), indexing="ij")
    di, dj = di.flatten(), dj.flatten()  # the 3 x 3 neighbourhood, centre at 4
    ni = i[rows, None] + di[None]  # (B_d, 9)
    nj = j[rows, None] + dj[None]
    inside = (ni >= 0) & (ni < h) & (nj >= 0) & (nj < w)
    r9 = rows[:, None].expand_as(ni)
    rr, ii, jj = r9[inside], ni[inside], nj[inside]
    weight[rr, ii, jj] = 0.0  # the neighbours are not negatives ...
    weight[rows, i[rows], j[rows]] = 1.0  # ... the point's cell is the positive
    target[rows, i[rows], j[rows]] = 1.0
    bce = F.binary_cross_entropy_with_logits(logits, target, weight=weight, reduction="none")
    heat = bce.sum(dim=(1, 2)).mean()
    if len(rows) == 0:
        return heat
    cells = net_out[rr, :, ii, jj]  # (M, 5)
    anchor = torch.stack([jj, ii], dim=1).float() * STRIDE_PX
    mean = anchor + STRIDE_PX * cells[:, 1:3]
    log_var = cells[:, 3:5].clamp(*LOG_VAR_RANGE_PX2)
    nll = 0.5 * (log_var + (uv_px[rr] - mean) ** 2 / torch.exp(log_var))
    offset = (torch.exp(BETA * log_var).detach() * nll).sum(dim=1).mean()
    return heat + offset


def _outputs(net: PointHeatmapNet, frames: np.ndarray) -> tuple[np.ndarray, ...]:
    """(uv_px, variance_px2, probability) of every frame, in batches."""
    parts: list[tuple[np.ndarray, ...]] = []
    with torch.no_grad():
        for start in range(0, len(frames), 256):
            parts.append(net.decode(net(torch.from_numpy(frames[start : start + 256]))))
    return tuple(np.concatenate(p) for p in zip(*parts, strict=True))


def point_report(net: PointHeatmapNet, data: FrameDataset) -> dict[str, Any]:
    """The detector on ``data`` (values: the point's (u, v) px; detected: (N, 1)): the
    detected flag's accuracy (missed: the label's point not found, false: found where
    the label has none), and over the frames both detect, the RMSE and median of the
    error per value (px), the fraction over 3 px, and NEES/dof."""
    uv, variance, probability = _outputs(net, data.frames)
    label = data.detected[:, 0] > 0.5
    found = probability > 0.5
    both = label & found
    error = uv[both] - data.values[both]
    report: dict[str, Any] = {
        "frames": len(data.frames),
        "frames_with_point": int(label.sum()),
        "detected_right": [round(float(np.mean(found == label)), 4)],
        "missed": int(np.sum(label & ~found)),
        "false": int(np.sum(found & ~label)),
    }
    if len(error):
        distance = np.linalg.norm(error, axis=1)
        report |= {
            "rmse_px": [round(float(v), 4) for v in np.sqrt(np.mean(error**2, axis=0))],
            "median_abs_px": [round(float(v), 4) for v in np.median(np.abs(error), axis=0)],
            "over_3px": round(float(np.mean(distance > 3.0)), 4),
            "nees_per_dof": round(float(np.mean(error**2 / variance[both])), 4),
        }
    return report


def fit_point_detector(
    data: FrameDataset, seed: int, epochs: int, held_out: float = 0.2, channels: int = 32
) -> tuple[PointHeatmapNet, dict[str, Any]]:
    """Train a :class:`PointHeatmapNet` on ``data`` (frames: crops, values: the point's
    (u, v) in each crop, detected (N, 1)); (the network, a report: data size, settings,
    per-epoch training loss, held-out errors: :func:`point_report` on the last
    ``held_out`` fraction of the episodes)."""
    if data.values.shape[1:] != (2,) or data.detected.shape[1:] != (1,):
        raise ValueError(
            f"a point detector's data has values (N, 2) and detected (N, 1), got "
            f"{data.values.shape} and {data.detected.shape}"
        )
    train, test = split(data, held_out)
    with reproducible(seed) as rng:
        net = PointHeatmapNet(channels)
        frames = torch.from_numpy(train.frames)
        uv = torch.as_tensor(np.nan_to_num(train.values)).float()
        detected = torch.as_tensor(train.detected[:, 0] > 0.5)
        losses = train_minibatches(
            net,
            len(uv),
            lambda index: _loss(net(frames[index]), uv[index], detected[index]),
            epochs,
            rng,
        )
    report = {
        "seed": seed,
        "epochs": epochs,
        "batch": BATCH,
        "learning_rate": LEARNING_RATE,
        "beta": BETA,
        "crop_px": list(data.frames.shape[2:][::-1]),
        "train_frames": len(train.frames),
        "train_episodes": len(np.unique(train.episode)),
        "held_out_episodes": len(np.unique(test.episode)),
        "train_loss": losses,
        "held_out": point_report(net, test),
    }
    return net, report


def save_point_detector(
    net: PointHeatmapNet, camera_px: tuple[int, int], path: Path, report: dict[str, Any]
) -> None:
    """Write ``path`` (.pt: architecture, camera image size, state dict) and its report
    (.json, with the file's sha256)."""
    saved = {
        "architecture": net.architecture(),
        "camera_px": list(camera_px),
        "state_dict": net.state_dict(),
    }
    save_weights(path, saved, report)


class LearnedPointDetector(SavedFrameNetwork):
    """A trained :class:`PointHeatmapNet` and its report, for one frame at a time.

    Args:
        path: the weight file; refused if missing or if its sha256 is not its report's.
    """

    net: PointHeatmapNet

    def __init__(self, path: Path) -> None:
        super().__init__(path, PointHeatmapNet)

    def detect(self, frame: np.ndarray) -> PointDetection:
        """One (H, W, 3) uint8 frame (H, W divisible by 4) -> its :class:`PointDetection`
        (on one torch thread: :meth:`SavedFrameNetwork.outputs`)."""
        image = torch.from_numpy(np.ascontiguousarray(frame.transpose(2, 0, 1))[None])
        with torch.no_grad():
            uv, variance, probability = self.net.decode(self.outputs(image))
        p = float(probability[0])
        return PointDetection(uv[0], variance[0], p, p > 0.5)
