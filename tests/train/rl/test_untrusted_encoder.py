"""An image encoder file is read as tensors and plain data only: a crafted file that
would run code on unpickling is refused in one line, and its code does not run."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from observer_gym.train.rl.pixel_encoder import load_encoder  # noqa: E402


class _Payload:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):  # what unpickling would call: write the marker file
        return (open, (str(self.marker), "w"))


def test_a_crafted_encoder_file_is_refused_and_runs_nothing(tmp_path):
    marker = tmp_path / "ran"
    crafted = tmp_path / "encoder.pt"
    torch.save({"state_dict": {}, "meta": _Payload(marker)}, crafted)
    with pytest.raises(ValueError, match="holds more than tensors and plain data"):
        load_encoder(str(crafted))
    assert not marker.exists()


def test_the_shipped_encoder_still_loads():
    encoder = load_encoder("ball_table")
    assert encoder.meta["targets"]
