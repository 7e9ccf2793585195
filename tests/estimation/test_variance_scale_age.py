"""The variance scale by the newest frame's age (estimation/learned/variance_scale.py:
VarianceScale, fit_variance_scale, the report's entry)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from observer_gym.estimation.learned.variance_scale import (
    VarianceScale,
    fit_variance_scale,
    load_variance_scale,
    parse_entry,
    variance_scale,
)

KNOTS_S = [0.0, 0.05, 0.1, 0.15, 0.2]


def true_log_scale(age_s: np.ndarray) -> np.ndarray:
    """A known scale, log-linear in the age per entry: 2 * exp(10 age), 0.5 * exp(-3 age)."""
    age_s = np.asarray(age_s, dtype=float)
    return np.stack([np.log(2.0) + 10.0 * age_s, np.log(0.5) - 3.0 * age_s], axis=-1)


def test_the_fit_recovers_a_known_log_linear_scale_from_noisy_episodes():
    rng = np.random.default_rng(0)
    ages = rng.uniform(0.0, 0.2, size=400)
    ratios = np.exp(true_log_scale(ages) + rng.normal(0.0, 0.3, size=(400, 2)))
    fitted = fit_variance_scale(ages, ratios, KNOTS_S)
    assert fitted.knots_age_s.tolist() == KNOTS_S
    # standard error of a knot's log ~ 0.3 / sqrt(~80 episodes) = 0.03
    assert np.allclose(np.log(fitted.scale), true_log_scale(np.array(KNOTS_S)), atol=0.1)
    for age in (0.0, 0.033, 0.12, 0.2):
        assert np.allclose(np.log(fitted.at(age)), true_log_scale(age), atol=0.1)


def test_without_noise_the_fit_is_exact_and_one_knot_is_the_geometric_mean():
    ages = np.linspace(0.0, 0.2, 9)
    ratios = np.exp(true_log_scale(ages))
    fitted = fit_variance_scale(ages, ratios, KNOTS_S)
    assert np.allclose(np.log(fitted.scale), true_log_scale(np.array(KNOTS_S)), atol=1e-12)
    constant = fit_variance_scale(ages, ratios, [0.0])
    assert np.allclose(constant.at(0.17), np.exp(np.mean(np.log(ratios), axis=0)))
    assert constant.to_entry() == pytest.approx(np.exp(np.mean(np.log(ratios), axis=0)).tolist())


def test_ages_outside_the_knots_are_held_at_the_end_knots():
    scale = parse_entry(
        {"knots_age_s": [0.0, 0.1, 0.2], "scale": [[1.0, 4.0], [2.0, 2.0], [8.0, 1.0]]},
        2,
        "test",
    )
    assert np.allclose(scale.at(0.0), [1.0, 4.0])
    assert np.allclose(scale.at(0.05), [np.sqrt(2.0), np.sqrt(8.0)])  # linear in log
    assert np.allclose(scale.at(0.2), [8.0, 1.0])
    assert np.allclose(scale.at(1.0), [8.0, 1.0])  # e.g. a missing frame's age
    assert np.allclose(scale.at(-0.01), [1.0, 4.0])


def test_the_fit_clamps_episodes_beyond_the_last_knot_to_it():
    # episodes at 0.3 s count at 0.2 s: with ratios of 4 there and at 0.2 s the knot is 4
    fitted = fit_variance_scale([0.0, 0.2, 0.3], [[1.0], [4.0], [4.0]], [0.0, 0.2])
    assert np.allclose(fitted.scale[:, 0], [1.0, 4.0])


def test_the_old_list_format_is_a_constant_scale_and_round_trips():
    report = {"variance_scale": {"measurements": [2.0, 3.0], "commands": {}}}
    scale = load_variance_scale(report, "measurements", 2)
    assert np.allclose(scale.at(0.0), [2.0, 3.0]) and np.allclose(scale.at(0.5), [2.0, 3.0])
    assert scale.is_constant and scale.to_entry() == [2.0, 3.0]
    assert variance_scale(report, "measurements", 2).tolist() == [2.0, 3.0]
    assert np.allclose(load_variance_scale(report, "rgb", 2).at(0.1), [1.0, 1.0])  # none: 1
    entry = {"knots_age_s": [0.0, 0.2], "scale": [[1.0, 2.0], [3.0, 4.0]]}
    assert parse_entry(entry, 2, "x").to_entry() == entry


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ([1.0, -1.0], "must be 2 positive finite numbers"),
        ([1.0, 2.0, 3.0], "must be 2 positive finite numbers"),
        ("big", "must be 2 positive finite numbers"),
        ({"knots_age_s": [0.0, 0.1]}, "has the keys 'knots_age_s' and 'scale'"),
        ({"knots_age_s": [0.1, 0.0], "scale": [[1, 1], [1, 1]]}, "strictly increasing"),
        ({"knots_age_s": [-0.1, 0.0], "scale": [[1, 1], [1, 1]]}, "strictly increasing ages >= 0"),
        ({"knots_age_s": [], "scale": []}, "non-empty"),
        ({"knots_age_s": [0.0, 0.1], "scale": [[1, 1]]}, "scale must be 2 x 2 positive"),
        ({"knots_age_s": [0.0, 0.1], "scale": [[1, 1], [1, np.inf]]}, "positive finite"),
    ],
)
def test_a_bad_entry_is_refused_with_what_is_wrong(entry, message):
    report = {"variance_scale": {"rgb": entry}}
    with pytest.raises(ValueError, match=message) as caught:
        load_variance_scale(report, "rgb", 2)
    assert "variance scale for 'rgb'" in str(caught.value)
    assert "benchmarks/learned_variance_scale.py" in str(caught.value)


def test_the_constant_reader_refuses_an_age_dependent_scale():
    report = {"variance_scale": {"rgb": {"knots_age_s": [0.0, 0.2], "scale": [[1.0], [2.0]]}}}
    with pytest.raises(ValueError, match="depends on the newest frame's age or the declared"):
        variance_scale(report, "rgb", 1)


def test_a_fit_with_a_knot_no_episode_reaches_is_refused():
    with pytest.raises(ValueError, match="do not determine a scale at every knot"):
        fit_variance_scale([0.0, 0.01, 0.02], [[1.0], [1.0], [1.0]], [0.0, 0.1, 0.2])
    with pytest.raises(ValueError, match="positive and finite"):
        fit_variance_scale([0.0, 0.1], [[1.0], [0.0]], [0.0])
    with pytest.raises(ValueError, match=r"ages_s must be \(E,\)"):
        fit_variance_scale([0.0, 0.1, 0.2], [[1.0], [2.0]], [0.0])
    with pytest.raises(ValueError, match="strictly increasing"):
        fit_variance_scale([0.0, 0.1], [[1.0], [2.0]], [0.1, 0.1])


def test_a_held_fit_keeps_the_held_knots_and_recovers_the_later_ones():
    """Episodes from a scale that is 2 (entry 0) and 1 (entry 1) up to 0.1 s and grows
    to 10 and 5 at 0.2 s: held at (2, 1) up to 0.1 s, the fit finds the 0.2 s knot from
    the later episodes alone; a free fit of the same data on the knots 0 and 0.2 s
    cannot hold the young ages."""
    rng = np.random.default_rng(1)
    ages = rng.uniform(0.0, 0.2, 200)
    true_x = np.exp(np.interp(ages, [0.0, 0.1, 0.2], np.log([2.0, 2.0, 10.0])))
    ratios = np.stack([true_x, true_x / 2.0], axis=1)
    held = fit_variance_scale(ages, ratios, [0.0, 0.1, 0.2], held=(0.1, [2.0, 1.0]))
    assert np.array_equal(held.scale[:2], [[2.0, 1.0], [2.0, 1.0]])
    assert np.allclose(held.scale[2], [10.0, 5.0])
    free = fit_variance_scale(ages, ratios, [0.0, 0.2])
    assert free.at(0.0)[0] < 1.5 and free.at(0.1)[0] > 2.5  # 1.28 and 2.95, not 2


def test_a_bad_hold_is_refused_with_what_is_wrong():
    ages, ratios = [0.0, 0.1, 0.2], [[1.0], [2.0], [4.0]]
    with pytest.raises(ValueError, match="hold_to_s must be one of the knots"):
        fit_variance_scale(ages, ratios, [0.0, 0.1, 0.2], held=(0.05, [1.0]))
    with pytest.raises(ValueError, match="hold_to_s must be one of the knots"):
        fit_variance_scale(ages, ratios, [0.0, 0.1, 0.2], held=(0.2, [1.0]))  # nothing to fit
    with pytest.raises(ValueError, match="held scale must be 1 positive"):
        fit_variance_scale(ages, ratios, [0.0, 0.1, 0.2], held=(0.1, [-1.0]))


def test_a_hand_built_record_evaluates_per_entry():
    scale = VarianceScale(np.array([0.0, 1.0]), np.array([[1.0, 1.0], [np.e, 1.0]]))
    assert scale.n_out == 2
    assert np.allclose(scale.at(0.5), [np.exp(0.5), 1.0])


# BallTable's observers read their shipped report's scale by age


@pytest.mark.parametrize("obs_mode", ["measurements", "rgb"])
def test_ball_tables_shipped_scale_grows_with_the_age_for_the_tilt(obs_mode):
    """Past the network's training latency (0-0.05 s) its tilt and tilt rate (entries 4:8)
    err far more than it claims: the fitted scale grows with the age there (the ball's
    position does not: its own variance grows faster, docs/learned_observers.md)."""
    from observer_gym.estimation.ball_table.learned import WEIGHTS

    report = json.loads(WEIGHTS.with_suffix(".json").read_text())
    scale = load_variance_scale(report, obs_mode, 8)
    assert not scale.is_constant
    assert np.all(scale.at(0.2)[4:8] > 3.0 * scale.at(0.0)[4:8])
    assert np.allclose(scale.at(0.5), scale.at(0.2))  # held at the last knot


def _spy_ages(observer, feature_ages: list[float] | None = None) -> list[float]:
    """Record the newest frame's age each call of ``observer.predict`` scales by (and the
    newest frame's age its features carry into ``feature_ages``)."""
    ages: list[float] = []
    predict = observer.predict

    def spy(features, age_s):
        ages.append(age_s)
        if feature_ages is not None:
            feature_ages.append(float(features[13]))  # the newest frame's age input
        return predict(features, age_s)

    observer.predict = spy
    return ages


def _ball_table(observer: str, latency_s: float):
    import gymnasium as gym

    from observer_gym.estimation import VisionObserver

    return VisionObserver(
        gym.make("observer_gym/BallTable-v0", obs_mode="measurements", latency_s=latency_s),
        observer=observer,
    )


def test_ball_tables_learned_scales_by_the_newest_frames_age_from_its_stamps():
    latency_s = 0.1
    env = _ball_table("learned", latency_s)
    try:
        observer = env.pipeline  # the LearnedObserver
        ages = _spy_ages(observer)
        env.reset(seed=0)
        newest_capture_s = -np.inf
        for _ in range(15):
            _, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
            for frame in info["frames"]:
                newest_capture_s = max(newest_capture_s, frame["capture_time_s"])
            now_s = float(info["time_s"])
            expected_age_s = now_s - newest_capture_s if np.isfinite(newest_capture_s) else 1.0
            assert ages[-1] == pytest.approx(expected_age_s)
            _, raw = observer.net.predict(observer.features.vector(now_s, np.zeros(2)))
            reported = np.diag(info["estimate"]["covariance"])
            assert np.allclose(reported, np.diag(raw) * observer.variance_scale.at(ages[-1]))
        assert min(ages) >= latency_s - 1e-9  # every frame is at least the latency old
    finally:
        env.close()


def test_ball_tables_learned_kf_scales_its_r_by_the_frames_age_at_delivery():
    latency_s = 0.1
    env = _ball_table("learned-kf", latency_s)
    try:
        feature_ages: list[float] = []
        ages = _spy_ages(env.pipeline.learned, feature_ages)
        env.reset(seed=0)
        for _ in range(20):
            env.step(np.zeros(2, dtype=np.float32))
        # fused outputs only (one in two frames), each at its delivery: the latency old,
        # not 0 (the network's mean reads the frame at its capture), and R is learned's
        # covariance with the features at delivery (their newest age that same age)
        assert len(ages) >= 3
        assert all(latency_s - 1e-9 <= age <= latency_s + 0.02 for age in ages), ages
        assert feature_ages == pytest.approx(ages)
    finally:
        env.close()


# benchmarks/learned_variance_scale.py --by-age

BENCHMARK = Path(__file__).resolve().parents[2] / "benchmarks" / "learned_variance_scale.py"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--by-age", "0,x"], "knots must be comma-separated, strictly increasing"),
        (["--by-age", "0.1,0"], "knots must be comma-separated, strictly increasing"),
        (["--by-age", "0,0.1"], "--by-age fits the geometric estimator by age"),
        (["--hold-to", "0.1"], "--hold-to must be one of --by-age's knots but the last"),
        (
            ["--estimator", "geometric", "--by-age", "0,0.1", "--hold-to", "0.1"],
            "--hold-to must be one of --by-age's knots but the last",
        ),
        (["--by-declared", "noise=0,1"], "NAME must be a number of the declared sensor"),
        (["--vary", "latency_s,bogus"], "options must be comma-separated, distinct names"),
        (["--vary", "latency_s,latency_s"], "options must be comma-separated, distinct names"),
        (["--vary", "latency_s"], "--vary names the options of --ranges study"),
        (["--by-declared", "frame_drop_prob=0.5,0"], "frame_drop_prob's knots must be"),
        (["--by-declared", "frame_drop_prob=0,0.5"], "--by-declared adds terms to a scale by age"),
        (
            [
                *("--estimator", "geometric", "--by-age", "0,0.1,0.2", "--hold-to", "0.1"),
                *("--by-declared", "frame_drop_prob=0,0.5"),
            ],
            "--hold-to holds a scale by age alone",
        ),
    ],
)
def test_a_bad_by_age_is_one_line_and_exit_code_2(args, message):
    result = subprocess.run(
        [sys.executable, str(BENCHMARK), "--env", "BallTable-v0", *args],
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and message in result.stderr


@pytest.mark.slow  # about 6 s: three short closed-loop episodes of the network
def test_the_by_age_fit_prints_an_age_dependent_scale_without_writing():
    from observer_gym.estimation.ball_table.learned import WEIGHTS

    before = WEIGHTS.with_suffix(".json").read_bytes()
    result = subprocess.run(
        [
            sys.executable,
            str(BENCHMARK),
            "--env",
            "BallTable-v0",
            "--seed",
            "3000000",
            "--episodes",
            "3",
            "--steps",
            "30",
            "--ranges",
            "study",
            "--estimator",
            "geometric",
            "--by-age",
            "0,0.2",
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    out = json.loads(result.stdout)
    scale = parse_entry(out["scale"], 8, "printed")
    assert scale.knots_age_s.tolist() == [0.0, 0.2]
    episodes = out["episodes_by_age"]
    assert len(episodes) == 3 and all(0.0 <= e["mean_age_s"] <= 0.2 for e in episodes)
    assert episodes[1]["mean_age_s"] > episodes[0]["mean_age_s"]  # the latency episode
    assert WEIGHTS.with_suffix(".json").read_bytes() == before  # no --write, no change


# --- terms by the declared sensor's numbers (DeclaredTerm)


def true_declared_log(noise_px: np.ndarray, drop: np.ndarray) -> np.ndarray:
    """A known additive log scale, 0 at 0 px and no drops, linear in the declared noise
    and the drop probability: entry 0 times 3 per px and 4 at half the frames dropped,
    entry 1 times 20 at 4 px (a network that claims too little past its training range)."""
    noise_px, drop = np.asarray(noise_px, dtype=float), np.asarray(drop, dtype=float)
    return np.stack(
        [np.log(3.0) * noise_px + np.log(4.0) * drop / 0.5, np.log(20.0) * noise_px / 4.0],
        axis=-1,
    )


def test_the_joint_fit_recovers_age_and_declared_terms_from_noisy_episodes():
    """Episodes vary the age, the declared noise or the drops in turn (the others at a
    default), as the study's do; the joint fit finds each term, 1 at its first knot."""
    rng = np.random.default_rng(2)
    n = 600
    which = np.arange(n) % 3
    ages = np.where(which == 0, rng.uniform(0.0, 0.2, n), 0.0)
    noise = np.where(which == 1, rng.uniform(0.0, 4.0, n), 0.5)
    drop = np.where(which == 2, rng.uniform(0.0, 0.5, n), 0.0)
    log_true = true_log_scale(ages) + true_declared_log(noise, drop)
    ratios = np.exp(log_true + rng.normal(0.0, 0.3, size=(n, 2)))
    declared = {
        "measurement_noise_std_px": (noise, [0.0, 1.0, 2.0, 4.0]),
        "frame_drop_prob": (drop, [0.0, 0.25, 0.5]),
    }
    fitted = fit_variance_scale(ages, ratios, KNOTS_S, declared=declared)
    assert fitted.declared_names == ("measurement_noise_std_px", "frame_drop_prob")
    assert all(np.array_equal(term.scale[0], [1.0, 1.0]) for term in fitted.declared)
    for age, noise_px, p in [(0.0, 0.5, 0.0), (0.1, 4.0, 0.0), (0.0, 0.5, 0.5), (0.2, 2.0, 0.3)]:
        got = np.log(fitted.at(age, {"measurement_noise_std_px": noise_px, "frame_drop_prob": p}))
        expected = true_log_scale(age) + true_declared_log(noise_px, p)
        assert np.allclose(got, expected, atol=0.15), (age, noise_px, p, got, expected)
    # and it round-trips through the report's entry
    again = parse_entry(json.loads(json.dumps(fitted.to_entry())), 2, "x")
    assert np.allclose(
        again.at(0.1, {"measurement_noise_std_px": 3.0, "frame_drop_prob": 0.2}),
        fitted.at(0.1, {"measurement_noise_std_px": 3.0, "frame_drop_prob": 0.2}),
    )


def test_an_age_only_fit_of_the_same_episodes_misses_the_noise():
    """Without the declared term the 4 px episodes' ratio (x 20 in entry 1) is averaged
    into the young ages' factor: at 4 px it claims too little by far more than the band."""
    rng = np.random.default_rng(3)
    noise = rng.uniform(0.0, 4.0, 300)
    ratios = np.exp(true_declared_log(noise, np.zeros(300)))
    age_only = fit_variance_scale(np.zeros(300), ratios, [0.0])
    assert np.exp(true_declared_log(4.0, 0.0))[1] / age_only.at(0.0)[1] > 3.0


def test_a_scale_with_a_declared_term_needs_its_number():
    scale = parse_entry(
        {
            "knots_age_s": [0.0],
            "scale": [[2.0]],
            "declared": {
                "measurement_noise_std_px": {"knots": [0.0, 4.0], "scale": [[1.0], [16.0]]}
            },
        },
        1,
        "x",
    )
    assert not scale.is_constant
    assert np.allclose(scale.at(0.3, {"measurement_noise_std_px": 2.0}), [8.0])  # 2 x 4
    assert np.allclose(scale.at(0.3, {"measurement_noise_std_px": 9.0}), [32.0])  # held
    with pytest.raises(ValueError, match="depends on the declared measurement_noise_std_px"):
        scale.at(0.3)
    with pytest.raises(ValueError, match="depends on the declared measurement_noise_std_px"):
        scale.at(0.3, {"frame_drop_prob": 0.1})


@pytest.mark.parametrize(
    ("declared", "message"),
    [
        ({"noise": {"knots": [0.0], "scale": [[1.0]]}}, "not a number of the declared sensor"),
        ({"image_size_px": {"knots": [0.0], "scale": [[1.0]]}}, "not a number of the declared"),
        ({"frame_drop_prob": {"knots": [0.0]}}, "needs 'knots' and 'scale'"),
        (
            {"frame_drop_prob": {"knots": [0.2, 0.1], "scale": [[1.0], [1.0]]}},
            "strictly increasing values >= 0",
        ),
        (
            {"frame_drop_prob": {"knots": [0.0, 0.5], "scale": [[2.0], [1.0]]}},
            "first knot must be 1",
        ),
        ({"frame_drop_prob": {"knots": [0.0, 0.5], "scale": [[1.0], [-1.0]]}}, "positive finite"),
        ([1.0], "must map sensor numbers to terms"),
    ],
)
def test_a_bad_declared_term_is_refused_with_what_is_wrong(declared, message):
    entry = {"knots_age_s": [0.0], "scale": [[1.0]], "declared": declared}
    with pytest.raises(ValueError, match=message) as caught:
        parse_entry(entry, 1, "variance scale for 'measurements'")
    assert "benchmarks/learned_variance_scale.py" in str(caught.value)


def test_a_declared_term_no_episode_varies_is_refused():
    with pytest.raises(ValueError, match="do not determine a scale at every knot"):
        fit_variance_scale(
            [0.0, 0.0, 0.0],
            [[1.0], [2.0], [3.0]],
            [0.0],
            declared={"measurement_noise_std_px": ([0.5, 0.5, 0.5], [0.0, 1.0])},
        )
