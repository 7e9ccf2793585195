"""``observer-gym reproduce linderoth2010`` with a small budget: the printed table, the
JSON figures against the paper's claims and the bound, and the plots."""

from __future__ import annotations

import json
import re

import pytest

from observer_gym.train.cli import main
from observer_gym.train.experiments.reproduce import linderoth2010


def test_reproduce_linderoth2010_small(tmp_path, capsys):
    out = tmp_path / "rep"
    code = main(
        ["reproduce", "linderoth2010", "--out", str(out), "--runs", "8", "--single-runs", "3"]
    )
    assert code in (0, None)
    text = capsys.readouterr().out
    assert "frames until the 8 tracks agree" in text and "| 6-9 " in text
    results = json.loads((out / "results.json").read_text())
    two = results["two_cameras"]
    # After frame 1 the position covariance is nearly a line along camera 1's viewline.
    assert min(two["axis_ratio_frame1"]) > 300.0
    assert max(two["major_axis_to_viewline_deg"]) < 2.0
    # The paper: the position stabilises and the velocity is reasonable after ~4 frames.
    assert all(k is not None and k <= 4 for k in two["frames_to_position"])
    assert all(k is not None and k <= 6 for k in two["frames_to_velocity"])
    assert max(two["position_error_frame4_m"]) < 0.03
    outliers = results["outliers"]
    assert outliers["injected"] >= 3 and outliers["rejected"] == outliers["injected"]
    assert outliers["false_rejections"] <= 2
    single = results["single_camera"]
    # The paper's single-camera claim: tracks from inits 70 m off agree within 6-9 frames.
    assert all(k is not None and k <= 9 for k in single["frames_tracks_agree"])
    # Convergence to the truth cannot come within 9 frames: the pixels' CRLB alone leaves
    # a largest position std of > 10 cm there, and the tracks that converge do so later.
    assert min(single["crlb_position_std_frame9_m"]) > 0.10
    converged = [k for k in single["frames_to_converge"] if k is not None]
    assert len(converged) >= 8 and min(converged) > 9
    # With the filter's defaults (accel noise 0.5) gravity is blurred: none converge.
    assert all(k is None for k in results["single_camera_filter_defaults"]["frames_to_converge"])
    for name in results["plots"]:
        assert (out / name).stat().st_size > 10_000
    plots = ", ".join(str(out / name) for name in results["plots"])
    assert f"Wrote {plots} and {out / 'results.json'}" in text
    # no reprs of dicts, lists, unrounded floats or arrays
    assert not re.search(r"\{'|\[|\d\.\d{6,}|array\(", text)


@pytest.mark.parametrize("which", ["two", "single"])
def test_ellipse_figures_have_legend_colour_bar_and_units(which):
    """Both ellipse figures: the two views' axes in metres, a legend naming every marker,
    and a colour bar saying the colour is the frame's capture time in ms."""
    if which == "two":
        fig = linderoth2010.two_camera_figure(linderoth2010.run_two_cameras(1, 0.5, 0))
    else:
        fig = linderoth2010.single_camera_figure(linderoth2010.run_single_camera(1, 0.5, 0))
    bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    plots = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert len(bars) == 1
    assert bars[0].get_ylabel() == "capture time of frame k (ms after release)"
    top, side = plots[:2]
    assert (top.get_xlabel(), top.get_ylabel()) == ("x (m)", "y (m)")
    assert (side.get_xlabel(), side.get_ylabel()) == ("x (m)", "z (m)")
    legend = side.get_legend()
    assert legend is not None
    assert [t.get_text() for t in legend.get_texts()] == [
        "true flight",
        "estimate after frame k",
        "true position at frame k",
        "2-sigma position ellipse",
        "camera",
    ]
    for ax in plots:  # every axes labelled, with units
        assert re.search(r"\(.+\)", ax.get_xlabel()) and re.search(r"\(.+\)", ax.get_ylabel())
    if which == "single":
        errors = plots[2]
        assert errors.get_legend() is not None
        assert len(errors.get_legend().get_texts()) == 3
