"""Our hyperparameters in RL Baselines3 Zoo's format, so that Zoo trains our envs with our
tuned values:

    python -m rl_zoo3.train --algo ppo --env observer_gym/BallTable-v0 \\
        --gym-packages observer_gym.envs -conf <.../zoo/ppo_ball_table_estimate.yml> \\
        --eval-env-kwargs "obs_mode:'measurements'"

One file per algorithm, system and ``--obs`` type ships in
``observer_gym/train/rl/hyperparams/zoo/`` (:func:`zoo_path`), each holding one entry keyed
by the env id. They are generated from ``hyperparams/<algo>.yml`` by
:func:`write_zoo_files` (``python -m observer_gym.train.rl.zoo``), and a test holds the
shipped files equal to what it generates, so the two cannot drift apart.

How our keys become Zoo's (:func:`zoo_hyperparams`):

- ``env_kwargs``: the YAML's, plus ``obs_mode`` (what the observer reads);
- ``env_wrapper``: :func:`agent_wrapper` with the obs type, the observer (estimate) and
  the image options (rgb): it puts the env in the same wrappers as ``observer-gym train``
  (the VisionObserver, the image preprocessing, actions rescaled to [-1, 1]);
- ``policy``: the YAML's, else the one ``observer-gym train`` picks for the observation
  space (MlpPolicy, CnnPolicy, MultiInputPolicy);
- ``normalize``, ``n_envs``, ``n_timesteps``, ``policy_kwargs`` and the algorithm's
  keys as they are; ``policy_kwargs.activation_fn`` as Zoo's Python text
  (``nn.ReLU``); ``action_noise`` as ``noise_type`` / ``noise_std``;
- the keys Zoo takes on its command line instead (``vec_env`` -> ``--vec-env``,
  ``eval_freq`` -> ``--eval-freq``, ``eval_episodes`` -> ``--eval-episodes``,
  ``checkpoint_freq`` -> ``--save-freq``, ``torch_threads`` -> ``--num-threads``) are in
  the file's header, in the command that trains with them;
- ``env_kwargs`` again as ``--eval-env-kwargs`` in that command: rl_zoo3 builds its
  evaluation env with the YAML's ``env_kwargs`` only when ``--env-kwargs`` is given
  (:func:`eval_env_kwargs`).

``--obs estimate`` uses the system's default estimating observer on measurements (what
``observer-gym train --obs estimate`` picks); another observer is one edit of the
wrapper's ``observer`` (and of ``obs_mode``).
"""

from __future__ import annotations

import functools
import shlex
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import gymnasium as gym
import yaml

from observer_gym.envs import System, system_of
from observer_gym.envs.registration import PACKAGE_SYSTEMS
from observer_gym.train.core.observer_env import resolve_observer, wrap_observer
from observer_gym.train.core.tasks import task_of
from observer_gym.train.rl.agent_env import (
    OBS_TYPES,
    finish_agent_env,
    make_agent_env,
    observer_for,
)
from observer_gym.train.rl.hyperparams import ALGOS, HYPERPARAMS_DIR, resolve_hyperparams

if TYPE_CHECKING:
    from observer_gym.envs.core import CameraEnv

ZOO_DIR = HYPERPARAMS_DIR / "zoo"
WRAPPER = "observer_gym.train.rl.zoo.agent_wrapper"  # importable by Zoo (and its workers)
# our training keys that Zoo takes on its command line: key -> Zoo's option
COMMAND_LINE_KEYS = {
    "vec_env": "--vec-env",
    "eval_freq": "--eval-freq",
    "eval_episodes": "--eval-episodes",
    "checkpoint_freq": "--save-freq",
    "torch_threads": "--num-threads",
}
ACTIVATIONS = {"relu": "nn.ReLU", "tanh": "nn.Tanh", "elu": "nn.ELU"}  # Zoo's names


def agent_wrapper(
    env: gym.Env,
    obs: str,
    observer: str | None = None,
    image: Mapping[str, Any] | None = None,
    features: str | None = None,
    measurement_stack: int = 1,
) -> gym.Env:
    """``env`` (made by Zoo with ``env_kwargs``) as ``observer-gym train`` gives it to an
    agent reading ``obs``: for ``estimate``, wrapped in the VisionObserver of ``observer``
    (default: the system's on measurements); for ``rgb``, its frames preprocessed as
    ``image`` (:class:`~observer_gym.train.rl.agent_env.ImageOptions`) says; for
    ``measurements``, the last ``measurement_stack`` detections as one vector; with the
    feature set ``features``; actions rescaled to [-1, 1]. Zoo's ``env_wrapper`` names it.

    Raises:
        ValueError: ``env``'s obs_mode is not the one the observer reads, or a bad
            ``obs``, ``observer`` or ``image``.
    """
    system = system_of(env)
    feeding = observer_for(system.env_id, obs, "measurements", observer)
    entry = resolve_observer(system, feeding)
    obs_mode = entry.obs_mode
    made_with = cast("CameraEnv", env.unwrapped).config.obs_mode  # system_of said it is one
    if made_with != obs_mode:
        raise ValueError(
            f"observer {feeding!r} reads obs_mode {obs_mode!r}; the env was made with "
            f"obs_mode {made_with!r} (set env_kwargs.obs_mode: {obs_mode}; Zoo's evaluation "
            f"env takes its env_kwargs from --eval-env-kwargs: add "
            f"--eval-env-kwargs \"obs_mode:'{obs_mode}'\" and the file's other env_kwargs)"
        )
    return finish_agent_env(wrap_observer(env, entry), obs, image, features, measurement_stack)


class ZooFile(NamedTuple):
    """One shipped Zoo file: what it trains and its hyperparameters."""

    algo: str
    system: System
    obs: str
    hyperparams: dict[str, Any]  # the file's one entry, Zoo's keys
    options: dict[str, str]  # Zoo's command-line options for our other training keys

    @property
    def name(self) -> str:
        return zoo_name(self.algo, self.system.name, self.obs)


def zoo_name(algo: str, system: str, obs: str) -> str:
    """The file name of ``algo`` on ``system`` (its package name) reading ``obs``."""
    return f"{algo}_{system}_{obs}.yml"


def zoo_path(algo: str, env_id: str, obs: str) -> Path:
    """The shipped Zoo file of ``algo`` on ``env_id`` (with or without ``observer_gym/``)
    reading ``obs``; ValueError for an unknown algo, env or obs."""
    from observer_gym.envs import system_for_id

    if algo not in ALGOS:
        raise ValueError(f"unknown algo {algo!r}; allowed: {', '.join(ALGOS)}")
    if obs not in OBS_TYPES:
        raise ValueError(f"unknown obs {obs!r}; allowed: {', '.join(OBS_TYPES)}")
    return ZOO_DIR / zoo_name(algo, system_for_id(env_id).name, obs)


@functools.cache
def _default_policy(
    env_id: str,
    obs: str,
    image: tuple[tuple[str, Any], ...],
    env_kwargs: tuple[tuple[str, Any], ...],
    features: str | None,
) -> str:
    """The policy ``observer-gym train`` picks for the agent env's observation space."""
    from observer_gym.train.rl.learning import default_policy  # deferred: stable-baselines3

    env = make_agent_env(
        env_id, obs, env_kwargs=dict(env_kwargs), image=dict(image), features=features
    )
    try:
        return default_policy(env.observation_space)
    finally:
        env.close()


def zoo_hyperparams(env_id: str, algo: str, obs: str) -> ZooFile:
    """Our resolved hyperparameters of ``algo`` on ``env_id`` reading ``obs``
    (:func:`~observer_gym.train.rl.hyperparams.resolve_hyperparams`) in Zoo's keys."""
    from observer_gym.envs import system_for_id

    system = system_for_id(env_id)
    params = resolve_hyperparams(system.env_id, algo, obs)
    feeding = observer_for(system.env_id, obs)
    obs_mode = task_of(system).OBSERVERS[feeding][0]
    wrapper: dict[str, Any] = {"obs": obs}
    if obs == "estimate":
        wrapper["observer"] = feeding
    if obs == "rgb":
        wrapper["image"] = dict(params["image"])
    if obs == "measurements":
        wrapper["measurement_stack"] = params["measurement_stack"]
    if params["features"] is not None:
        wrapper["features"] = params["features"]
    policy = params["policy"] or _default_policy(
        system.env_id,
        obs,
        tuple(sorted(params["image"].items())),
        tuple(sorted(params["env_kwargs"].items())),
        params["features"],
    )
    zoo: dict[str, Any] = {
        "n_timesteps": params["n_timesteps"],
        "n_envs": params["n_envs"],
        "policy": policy,
        "env_kwargs": {"obs_mode": obs_mode, **params["env_kwargs"]},
        "env_wrapper": [{WRAPPER: wrapper}],
        "normalize": params["normalize"],
    }
    training = {
        "n_timesteps",
        "n_envs",
        "policy",
        "env_kwargs",
        "normalize",
        "image",
        "features",
        "measurement_stack",
    }
    for key, value in params.items():
        if key in training or key in COMMAND_LINE_KEYS:
            continue
        if key == "action_noise":
            zoo["noise_type"] = value["type"]
            zoo["noise_std"] = value["sigma"]
        elif key == "policy_kwargs" and "activation_fn" in value:
            zoo[key] = _python_dict(value)
        else:
            zoo[key] = value
    options = {option: str(params[key]) for key, option in COMMAND_LINE_KEYS.items()}
    return ZooFile(algo, system, obs, zoo, options)


def _python_dict(policy_kwargs: Mapping[str, Any]) -> str:
    """``policy_kwargs`` as the Python text Zoo evaluates: ``dict(..., activation_fn=nn.ReLU)``."""
    items = [
        f"{key}={ACTIVATIONS[value] if key == 'activation_fn' else repr(value)}"
        for key, value in policy_kwargs.items()
    ]
    return f"dict({', '.join(items)})"


def eval_env_kwargs(entry: ZooFile) -> list[str]:
    """Zoo's ``--eval-env-kwargs`` words carrying ``entry``'s ``env_kwargs``.

    rl_zoo3 (2.9.2 at least) builds its evaluation env with the YAML's ``env_kwargs``
    only when ``--env-kwargs`` is given on its command line; otherwise the eval env comes
    up with the env's defaults (``obs_mode="rgb"``), and the wrapper refuses it at the
    first evaluation. Each value is Python text, as Zoo evaluates it (``obs_mode:'state'``).
    """
    return ["--eval-env-kwargs"] + [
        f"{key}:{value!r}" for key, value in entry.hyperparams["env_kwargs"].items()
    ]


def _shell_word(word: str) -> str:
    """``word`` quoted for a POSIX shell; a word holding single quotes (Zoo's Python
    text) in double quotes when nothing in it is special there, for a readable command."""
    if "'" in word and not any(char in word for char in '"$`\\!'):
        return f'"{word}"'
    return shlex.quote(word)


def zoo_command(entry: ZooFile, conf: str | None = None) -> str:
    """The Zoo command line that trains ``entry`` from the file at ``conf`` (None: the
    shell's ``$(python -m observer_gym.train.rl.zoo path ...)`` of the shipped file).

    It carries the file's ``env_kwargs`` as ``--eval-env-kwargs`` (:func:`eval_env_kwargs`),
    so Zoo's evaluation env is the training env."""
    words = [
        "python", "-m", "rl_zoo3.train", "--algo", entry.algo, "--env", entry.system.env_id,
        "--gym-packages", "observer_gym.envs", "-conf",
    ]  # fmt: skip
    options = [word for option, value in entry.options.items() for word in (option, value)]
    tail = " ".join(_shell_word(word) for word in [*options, *eval_env_kwargs(entry)])
    if conf is not None:
        return f"{shlex.join([*words, conf])} {tail}"
    path = f"python -m observer_gym.train.rl.zoo path {entry.algo} {entry.system.short_id}"
    find = f'"$({path} {entry.obs})"'
    return f"{shlex.join(words)} {find} {tail}"


def zoo_text(entry: ZooFile) -> str:
    """The shipped file's text: a header (what it is, the command) and the entry."""
    header = [
        f"# {entry.algo.upper()} on {entry.system.env_id}, --obs {entry.obs}, in RL Baselines3 "
        "Zoo's format.",
        f"# Generated from observer_gym/train/rl/hyperparams/{entry.algo}.yml by "
        "'python -m observer_gym.train.rl.zoo write'; do not edit.",
        "# Train with (the options carry our training keys that Zoo takes on its command line):",
        f"#   {zoo_command(entry)}",
    ]
    body = yaml.safe_dump({entry.system.env_id: entry.hyperparams}, sort_keys=False)
    return "\n".join(header) + "\n" + body


def zoo_files() -> list[ZooFile]:
    """Every algorithm on every system of the package reading every obs type (the
    files shipped in ``hyperparams/zoo/``; a system added by ``register_system`` has
    none)."""
    return [
        zoo_hyperparams(system.env_id, algo, obs)
        for algo in ALGOS
        for system in PACKAGE_SYSTEMS
        for obs in OBS_TYPES
    ]


def write_zoo_files(directory: Path = ZOO_DIR) -> list[Path]:
    """Write :func:`zoo_files` into ``directory``; returns their paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for entry in zoo_files():
        path = directory / entry.name
        path.write_text(zoo_text(entry), encoding="utf-8")
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> None:
    """``python -m observer_gym.train.rl.zoo write``: (re)write the shipped files;
    ``... path ALGO ENV OBS``: print the path of one."""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m observer_gym.train.rl.zoo", description=__doc__
    )
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("write", help="write every Zoo file into the package")
    find = commands.add_parser("path", help="print the path of the Zoo file of ALGO on ENV")
    find.add_argument("algo", choices=ALGOS)
    find.add_argument("env", help="env id, with or without observer_gym/")
    find.add_argument("obs", choices=OBS_TYPES)
    args = parser.parse_args(argv)
    if args.command == "write":
        for written in write_zoo_files():
            print(written)
    else:
        try:
            print(zoo_path(args.algo, args.env, args.obs))
        except ValueError as exc:
            parser.error(str(exc))


if __name__ == "__main__":
    main()
