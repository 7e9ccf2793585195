"""The consistency study's frames part (train/experiments/consistency_study.py ``--frames``,
docs/results/consistency.md "From rendered frames"): its observers read rendered frames,
its command refuses what it does not study, its later options take the default cell's
episodes from the first option's sweep, and one episode per frame observer on BallTable
keeps the NEES/dof the study measured."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from observer_gym.train.experiments import consistency_study as study
from observer_gym.train.experiments.consistency_study import (
    FRAME_OPTIONS,
    FRAME_SYSTEMS,
    SYSTEMS,
    main,
    measure_consistency,
)


def test_every_frame_observer_reads_rendered_frames():
    from observer_gym.train.core.tasks import ball_catcher, ball_table, target_follower

    tasks = {
        "BallTable-v0": ball_table,
        "BallCatcher-v1": ball_catcher,
        "TargetFollower-v0": target_follower,
    }
    for env_id, frame_study in FRAME_SYSTEMS.items():
        assert env_id in SYSTEMS
        for observer in frame_study.observers:
            obs_mode, options = tasks[env_id].OBSERVERS[observer]
            assert obs_mode == "rgb" and options is not None, observer
        assert tuple(frame_study.options) == FRAME_OPTIONS
        for values in frame_study.options.values():
            assert values[0] == 0.0 and list(values) == sorted(set(values))


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--frames", "--systems", "BallCatcher-v2"], "--systems: ['BallCatcher-v2']"),
        (["--frames", "--options", "measurement_noise_px"], "--options: ['measurement_noise_px']"),
        (["--options", "image_noise_std"], "--options: ['image_noise_std']"),
    ],
)
def test_the_command_refuses_what_its_part_does_not_study(argv, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--out", str(tmp_path / "out"), *argv])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_later_options_take_the_default_cell_from_the_first_sweep(monkeypatch, tmp_path):
    """The latency sweep runs its values but the default; its table's default column is
    the image-noise sweep's default cell, episode for episode."""
    calls = []

    def fake_sweep(env_id, vary, observers, controllers, out_dir, **kwargs):
        ((key, values),) = vary.items()
        calls.append((env_id, key, values, tuple(observers), tuple(controllers), kwargs))
        rows = [
            {
                "observer": observer,
                key: value,
                "seed": seed,
                # NEES/dof 1 + value + 0.1 * seed: the default cell's differs per sweep
                "nees_mean": 4.0 * (1.0 + value + 0.1 * seed),
                "nees_dof": 4.0,
                "nis_ratio": None,
            }
            for value in values
            for observer in observers
            for seed in range(kwargs["episodes"])
        ]
        return SimpleNamespace(results={"episodes": rows})

    import observer_gym.train.experiments.sweep as sweep

    monkeypatch.setattr(sweep, "run_sweep", fake_sweep)
    text = study.run_study(
        tmp_path, ["BallTable-v0"], list(FRAME_OPTIONS), 3, 1, seed=0, frames=True
    )
    frame_study, system = FRAME_SYSTEMS["BallTable-v0"], SYSTEMS["BallTable-v0"]
    noise, latency = (frame_study.options[k] for k in FRAME_OPTIONS)
    assert [(c[1], c[2]) for c in calls] == [
        ("image_noise_std", list(noise)),
        ("latency_s", list(latency[1:])),
    ]
    for _, option, _, observers, controllers, kwargs in calls:
        assert observers == frame_study.observers and controllers == (system.controller,)
        assert kwargs["steps"] == system.steps
        # the latency sweep runs with the study's jitter (OPTION_ENV_KWARGS), the others not
        extra = {"latency_jitter_s": 0.01} if option == "latency_s" else {}
        assert kwargs["env_kwargs"] == {**system.env_kwargs, **extra}
    latency_table = text.split("latency_s\n")[1]
    row = next(line for line in latency_table.splitlines() if line.startswith("| kf "))
    # the default column: the first sweep's cell (1.1 pooled), not a run of its own
    assert row.split("|")[2].strip().startswith("1.10 ")
    assert (tmp_path / "frames_tables.md").read_text() == text
    assert not (tmp_path / "tables.md").exists()
    for key in FRAME_OPTIONS:
        assert (tmp_path / f"ball_table_frames_{key}.png").is_file()


# One episode of the study's default cell on BallTable (seed 0, the LQR, 300 steps,
# pushes at 0.5 Hz, frames without noise or latency), NEES/dof as the study pools it:
# measured (docs/results/consistency/ball_table_frames_image_noise_std/episodes.csv,
# seed 0) kf 0.84; learned 0.86 and learned-kf 0.29 with the "rgb" variance scale
# (estimation/ball_table/learned.json; the study's frames part re-run for BallTable on
# 2026-11-29, docs/results/consistency.md; 7.41 and 2.95 without it). The band is half
# to twice that. 10 s (kf) and 5-8 s each (learned, learned-kf) at a load of 3-5.
FRAME_EPISODE_NEES = {"kf": 0.84, "learned": 0.86, "learned-kf": 0.29}


@pytest.mark.slow
@pytest.mark.parametrize("observer", list(FRAME_EPISODE_NEES))
def test_one_ball_table_frame_episode_keeps_the_measured_nees(observer):
    system = SYSTEMS["BallTable-v0"]
    run = measure_consistency(
        "observer_gym/BallTable-v0", observer, system.controller, 1, system.steps, system.env_kwargs
    )
    (ratio,) = run.nees_ratios
    measured = FRAME_EPISODE_NEES[observer]
    assert ratio is not None and measured / 2 <= ratio <= 2 * measured, ratio
