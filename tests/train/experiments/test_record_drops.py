"""``observer-gym record`` marks the frames the sensor dropped (``frames_lost``): with no
latency and no jitter a 50 Hz camera captures once per 0.02 s step, so at every step
the frames delivered so far and the frames lost so far add up to the captures so far."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("minari")
pytest.importorskip("jax")
pytest.importorskip("h5py")

from observer_gym.train.experiments.record import record_experiment
from observer_gym.train.reports.dataset import read_recording

STEPS = 40


@pytest.mark.parametrize("drop_prob", [0.0, 0.3])
def test_delivered_and_lost_frames_add_up_to_the_captures(tmp_path, drop_prob):
    out = tmp_path / "dataset"
    record_experiment(
        "BallTable-v0", "kf-measurements", "lqr", 1, 11, out, steps=STEPS, progress=False,
        env_kwargs={"frame_drop_prob": drop_prob},
    )  # fmt: skip
    (episode,) = read_recording(out)
    delivered = np.cumsum(episode.infos["frame_count"][:, 0])
    lost = episode.infos["frames_lost"][:, 0]
    captures = np.arange(STEPS + 1) + 1  # the reset's frame, then one per step
    np.testing.assert_array_equal(delivered + lost, captures)
    assert np.all(np.diff(lost) >= 0)
    if drop_prob == 0.0:
        assert lost[-1] == 0
    else:  # 40 draws at 0.3: 12 expected; 3..21 holds with probability > 0.999
        assert 3 <= lost[-1] <= 21
        # a step whose frame was lost delivered nothing
        dropped_steps = np.flatnonzero(np.diff(lost)) + 1
        assert np.all(episode.infos["frame_count"][dropped_steps, 0] == 0)
