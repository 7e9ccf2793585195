"""A ``--hyperparam`` value outside its key's range is refused before training, in one
line naming the key and what it may be (exit 2, nothing written), not by an
AssertionError from stable-baselines3; and what SB3 still refuses past those checks is
one line too."""

from __future__ import annotations

import pytest

from observer_gym.train.cli import main
from observer_gym.train.rl.hyperparams import ALGOS, resolve_hyperparams

TRAIN = ["train", "--no-progress", "--obs", "state", "--timesteps", "64", "--n-envs", "1"]
TRAIN += ["--vec-env", "dummy"]

BAD = [  # (algo, --hyperparam, what the line says)
    ("ppo", "n_steps=0", "hyperparameter n_steps must be an integer >= 1, got 0"),
    ("ppo", "learning_rate=nan", "hyperparameter learning_rate must be a finite number > 0"),
    ("ppo", "learning_rate=-1e-4", "hyperparameter learning_rate must be a finite number > 0"),
    ("ppo", "batch_size=-4", "hyperparameter batch_size must be an integer >= 1, got -4"),
    ("ppo", "batch_size=1", "batch_size must be >= 2 with normalize_advantage"),
    ("ppo", "gamma=1.5", "hyperparameter gamma must be a number in [0, 1], got 1.5"),
    ("ppo", "gae_lambda=-0.1", "hyperparameter gae_lambda must be a number in [0, 1]"),
    ("ppo", "n_epochs=0", "hyperparameter n_epochs must be an integer >= 1, got 0"),
    ("ppo", "clip_range=0", "hyperparameter clip_range must be a finite number > 0, got 0"),
    ("ppo", "n_steps=64.5", "hyperparameter n_steps must be an integer >= 1, got 64.5"),
    ("ppo", "normalize.clip_obs=-1", "hyperparameter normalize.clip_obs must be a finite"),
    ("ppo", "normalize.clip=1", "unknown hyperparameter normalize.clip"),
    ("sac", "tau=0", "hyperparameter tau must be a number in (0, 1], got 0"),
    ("sac", "buffer_size=0", "hyperparameter buffer_size must be an integer >= 1, got 0"),
    ("sac", "ent_coef=auto_x", "hyperparameter ent_coef must be auto, auto_<number > 0>"),
    ("td3", "train_freq=0", "hyperparameter train_freq must be an integer >= 1 or"),
    ("td3", "learning_starts=-1", "hyperparameter learning_starts must be an integer >= 0"),
    ("td3", "policy_delay=0", "hyperparameter policy_delay must be an integer >= 1, got 0"),
]


@pytest.mark.parametrize(("algo", "hyperparam", "says"), BAD)
def test_a_bad_hyperparameter_value_is_one_line_before_training(
    tmp_path, capsys, algo, hyperparam, says
):
    out = tmp_path / "run"
    argv = [*TRAIN, "--algo", algo, "--hyperparam", hyperparam, "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("observer-gym train: error: ") and err.count("\n") == 1, err
    assert says in err
    assert not out.exists()


def test_the_shipped_yaml_values_keep_the_rules():
    for algo in ALGOS:
        for env in ("BallTable-v0", "BallCatcher-v1", "TargetFollower-v0"):
            for obs in ("state", "estimate", "rgb"):
                resolve_hyperparams(f"observer_gym/{env}", algo, obs)


def test_the_library_refuses_as_the_command(tmp_path):
    with pytest.raises(ValueError, match=r"gamma must be a number in \[0, 1\], got 2"):
        resolve_hyperparams("observer_gym/BallTable-v0", "ppo", "state", {"gamma": 2})


@pytest.mark.slow  # builds the envs and imports PyTorch (~8 s)
def test_what_sb3_refuses_past_the_checks_is_one_line(tmp_path, capsys, monkeypatch):
    from stable_baselines3 import PPO

    def refuse(self):
        raise AssertionError("`n_steps * n_envs` must be greater than 1")

    monkeypatch.setattr(PPO, "_setup_model", refuse)
    out = tmp_path / "run"
    assert main([*TRAIN, "--algo", "ppo", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert "PPO refuses the hyperparameters: `n_steps * n_envs` must be greater than 1" in err
    assert not (out / "state.json").exists()


@pytest.mark.slow  # builds the envs and imports PyTorch (~8 s)
def test_a_layer_pytorch_refuses_is_one_line_and_leaves_the_folder_free(tmp_path, capsys):
    out = tmp_path / "run"
    argv = [*TRAIN, "--algo", "ppo", "--out", str(out)]
    assert main([*argv, "--hyperparam", "policy_kwargs.net_arch=[-5]"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert "PPO refuses the hyperparameters: " in err and "negative dimension" in err
    assert not (out / "config.json").exists()  # the folder takes a new run
