"""Hyperparameters of ``observer-gym train``: YAML files shipped with the package, one per
algorithm (``hyperparams/ppo.yml``, ``sac.yml``, ``td3.yml``), keyed by env id. An env
without an entry there takes its task module's ``HYPERPARAMS[algo]`` (same format) or, if
it has none, the defaults (:func:`env_entry`).

An env's entry holds two kinds of keys:

- training keys (:data:`TRAINING_DEFAULTS`): ``n_timesteps`` (the default
  ``--timesteps``), ``n_envs``, ``vec_env`` (subproc or dummy), ``normalize`` (false or
  VecNormalize's options), ``image`` (:class:`~observer_gym.train.rl.agent_env.ImageOptions`
  for ``--obs rgb``), ``checkpoint_freq`` and ``eval_freq`` (env steps), ``eval_episodes``,
  ``torch_threads``, ``policy`` (default: MlpPolicy for a vector, CnnPolicy for an
  image, MultiInputPolicy for a Dict), ``env_kwargs`` (``gym.make`` options, e.g. a
  smaller camera image for ``--obs rgb``; ``--env-option`` overrides them) and
  ``features`` (null or a feature set of :mod:`observer_gym.train.rl.features` that replaces
  or extends a state or estimate observation) and ``measurement_stack`` (how many of the
  newest measurements an agent trained with ``--obs measurements`` reads, 1 to 16);
- everything else goes to the algorithm's constructor (PPO's ``n_steps``, ...), checked
  against its signature (:func:`algorithm_parameters`: its public parameters but those
  ``observer-gym train`` sets itself) and its value against the key's rule
  (:data:`ALGORITHM_RULES`: ``n_steps`` an integer >= 1, ``gamma`` in [0, 1], ...), so a
  bad value is refused naming the key and its range before stable-baselines3 sees it.
  Two values are written as text and built on use:
  ``policy_kwargs.activation_fn`` (relu, tanh, elu) and ``action_noise``
  (``{type: normal, sigma: 0.1}``, in the [-1, 1] action units).

An optional ``obs`` section overrides keys per ``--obs`` type. Command-line overrides are
``KEY=VALUE`` with dotted keys for nested values (``normalize.norm_reward=False``,
``policy_kwargs.net_arch=[128,128]``). The resolved dict is what a run's config.json
records, so a run can be repeated from it alone.
"""

from __future__ import annotations

import copy
import difflib
import importlib
import inspect
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import yaml

from observer_gym.train.core.algorithms import ALGOS, algorithm_class
from observer_gym.train.rl.measurement_input import check_stack

if TYPE_CHECKING:
    pass

HYPERPARAMS_DIR = Path(__file__).parent / "hyperparams"

TRAINING_DEFAULTS: dict[str, Any] = {
    "n_timesteps": 100_000,
    "n_envs": 1,
    "vec_env": "subproc",
    "normalize": False,
    "image": {"size_px": 84, "grayscale": True, "frame_stack": 4},
    "checkpoint_freq": 10_000,
    "eval_freq": 10_000,
    "eval_episodes": 5,
    "torch_threads": 1,
    "policy": None,
    "env_kwargs": {},
    "features": None,
    "measurement_stack": 1,
}
INTEGER_KEYS = ("n_timesteps", "n_envs", "checkpoint_freq", "eval_freq", "eval_episodes")
VEC_ENVS = ("subproc", "dummy")
ACTIVATIONS = ("relu", "tanh", "elu")


def _set_dotted(params: dict[str, Any], dotted: str, value: Any) -> None:
    *parents, leaf = dotted.split(".")
    node = params
    for key in parents:
        if not isinstance(node.get(key), dict):
            node[key] = {}
        node = node[key]
    node[leaf] = value


def _merge(base: dict[str, Any], extra: Mapping[str, Any]) -> dict[str, Any]:
    for key, value in extra.items():
        if isinstance(value, Mapping) and isinstance(base.get(key), dict):
            _merge(base[key], value)
        else:
            base[key] = copy.deepcopy(value)
    return base


def env_entry(env_id: str, algo: str) -> Mapping[str, Any]:
    """The hyperparameters of ``algo`` on ``env_id`` before the defaults: the entry of
    ``hyperparams/<algo>.yml`` for the env, else the ``HYPERPARAMS[algo]`` of its system's
    task module (a system added from outside carries its own), else none (the training
    defaults and the algorithm's own). ValueError for an unknown env."""
    from observer_gym.envs import system_for_id

    system = system_for_id(env_id)
    entries = yaml.safe_load((HYPERPARAMS_DIR / f"{algo}.yml").read_text()) or {}
    if system.env_id in entries:
        return entries[system.env_id]
    task = importlib.import_module(system.module("task"))
    return getattr(task, "HYPERPARAMS", {}).get(algo, {})


def resolve_hyperparams(
    env_id: str, algo: str, obs: str, overrides: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The hyperparameters of ``algo`` on ``env_id`` with ``obs``: the defaults, the YAML
    entry, its ``obs`` section, then ``overrides`` (dotted keys), with the training keys
    checked (:func:`check_training_keys`) but not the algorithm's: this imports neither
    stable-baselines3 nor PyTorch.

    Raises:
        ValueError: an unknown algo or env, or a bad training value.
    """
    if algo not in ALGOS:
        raise ValueError(f"unknown algo {algo!r}; allowed: {', '.join(ALGOS)}")
    entry = dict(copy.deepcopy(env_entry(env_id, algo)))
    by_obs = entry.pop("obs", None) or {}
    params = _merge(copy.deepcopy(TRAINING_DEFAULTS), entry)
    _merge(params, by_obs.get(obs) or {})
    for dotted, value in (overrides or {}).items():
        _set_dotted(params, dotted, value)
    check_training_keys(params)
    check_algorithm_values(params, algo)
    return params


def load_hyperparams(
    env_id: str, algo: str, obs: str, overrides: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The resolved hyperparameters of ``algo`` on ``env_id`` with ``obs``
    (:func:`resolve_hyperparams`), every key checked: a key that is no training key must
    be one of :func:`algorithm_parameters` (this imports stable-baselines3).

    Raises:
        ValueError: an unknown algo, an env without an entry, an unknown key or a bad
            training value, naming it and what is allowed.
    """
    params = resolve_hyperparams(env_id, algo, obs, overrides)
    check_algorithm_keys(params, algo)
    return params


# Constructor parameters of the SB3 classes that observer-gym train sets itself, with
# what sets them; they are no hyperparameters.
SET_BY_TRAIN = {
    "env": "--env and --obs",
    "seed": "--seed",
    "device": "always cpu",
    "verbose": "always 0",
}


def algorithm_parameters(algo: str) -> tuple[str, ...]:
    """The constructor parameters of ``algo``'s SB3 class that a hyperparameter may set,
    sorted: the public ones (no leading underscore) but ``policy`` (a training key) and
    those of :data:`SET_BY_TRAIN`."""
    cls = algorithm_class(algo)
    skip = {"self", "policy", *SET_BY_TRAIN}
    return tuple(
        sorted(
            name
            for name in inspect.signature(cls.__init__).parameters
            if not name.startswith("_") and name not in skip
        )
    )


def check_algorithm_keys(params: Mapping[str, Any], algo: str) -> None:
    """ValueError unless every key of ``params`` is a training key or one of
    :func:`algorithm_parameters`; the message names the allowed keys (and the closest
    one to a misspelt key)."""
    allowed = algorithm_parameters(algo)
    unknown = sorted(set(params) - set(TRAINING_DEFAULTS) - set(allowed))
    if not unknown:
        return
    name = algorithm_class(algo).__name__
    set_here = [key for key in unknown if key in SET_BY_TRAIN]
    if set_here:
        raise ValueError(
            "not hyperparameters, observer-gym train sets them: "
            + ", ".join(f"{key} ({SET_BY_TRAIN[key]})" for key in set_here)
        )
    close = difflib.get_close_matches(unknown[0], [*TRAINING_DEFAULTS, *allowed], n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise ValueError(
        f"unknown hyperparameter(s) {unknown} for {name}{hint}; allowed: training keys "
        f"{', '.join(TRAINING_DEFAULTS)} and {name}'s {', '.join(allowed)}"
    )


def check_training_keys(params: Mapping[str, Any]) -> None:
    """ValueError for a bad value of a training key (:data:`TRAINING_DEFAULTS`) or of
    the two text values built on use (``policy_kwargs.activation_fn``,
    ``action_noise``)."""
    for key in INTEGER_KEYS:
        value = params[key]
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
            raise ValueError(f"hyperparameter {key} must be an integer >= 1, got {value!r}")
    if params["vec_env"] not in VEC_ENVS:
        raise ValueError(f"vec_env must be one of {', '.join(VEC_ENVS)}, got {params['vec_env']!r}")
    if not (params["features"] is None or isinstance(params["features"], str)):
        raise ValueError(
            f"features must be null or a feature set's name, got {params['features']!r}"
        )
    check_stack(params["measurement_stack"])
    if not isinstance(params["env_kwargs"], Mapping):
        raise ValueError(f"env_kwargs must be a mapping, got {params['env_kwargs']!r}")
    if not (params["normalize"] is False or isinstance(params["normalize"], Mapping)):
        raise ValueError(
            f"normalize must be false or VecNormalize's options, got {params['normalize']!r}"
        )
    activation = (params.get("policy_kwargs") or {}).get("activation_fn")
    if activation is not None and activation not in ACTIVATIONS:
        raise ValueError(
            f"policy_kwargs.activation_fn must be one of {', '.join(ACTIVATIONS)}, "
            f"got {activation!r}"
        )
    noise = params.get("action_noise")
    sigma = noise.get("sigma") if isinstance(noise, Mapping) else None
    if noise is not None and not (
        isinstance(noise, Mapping)
        and noise.get("type") == "normal"
        and isinstance(sigma, int | float)
        and not isinstance(sigma, bool)
        and sigma > 0
    ):
        raise ValueError(f"action_noise must be {{type: normal, sigma: > 0}}, got {noise!r}")


class Rule(NamedTuple):
    """What a hyperparameter's value may be: ``allowed`` says it, ``check`` tests it."""

    allowed: str
    check: Callable[[Any], bool]


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _int_from(low: int) -> Rule:
    return Rule(f"an integer >= {low}", lambda v: _is_int(v) and v >= low)


def _real_above(low: float, inclusive: bool = False) -> Rule:
    sign = ">=" if inclusive else ">"
    return Rule(
        f"a finite number {sign} {low:g}",
        lambda v: _is_real(v) and (v >= low if inclusive else v > low),
    )


def _optional(rule: Rule) -> Rule:
    return Rule(f"null or {rule.allowed}", lambda v: v is None or rule.check(v))


def _sac_ent_coef(value: Any) -> bool:
    if isinstance(value, str) and (value == "auto" or value.startswith("auto_")):
        try:
            return value == "auto" or float(value.removeprefix("auto_")) > 0
        except ValueError:
            return False
    return _is_real(value) and value >= 0


def _train_freq(value: Any) -> bool:
    if isinstance(value, list | tuple):
        return len(value) == 2 and _is_int(value[0]) and value[0] >= 1 and value[1] in TRAIN_UNITS
    return _is_int(value) and value >= 1


TRAIN_UNITS = ("step", "episode")
_BOOL = Rule("true or false", lambda v: isinstance(v, bool))
_UNIT = Rule("a number in [0, 1]", lambda v: _is_real(v) and 0 <= v <= 1)
_POSITIVE = _real_above(0)
_NONNEGATIVE = _real_above(0, inclusive=True)
_COMMON_RULES = {
    "learning_rate": _POSITIVE,
    "gamma": _UNIT,
    "batch_size": _int_from(1),
    "n_steps": _int_from(1),
    "use_sde": _BOOL,
    "sde_sample_freq": _int_from(-1),
    "stats_window_size": _int_from(1),
    "policy_kwargs": Rule("a mapping", lambda v: isinstance(v, Mapping)),
    "tensorboard_log": Rule("null or a folder", lambda v: v is None or isinstance(v, str)),
}
_OFF_POLICY_RULES = {
    "buffer_size": _int_from(1),
    "learning_starts": _int_from(0),
    "tau": Rule("a number in (0, 1]", lambda v: _is_real(v) and 0 < v <= 1),
    "train_freq": Rule("an integer >= 1 or [integer >= 1, step|episode]", _train_freq),
    "gradient_steps": Rule("an integer >= 1, or -1", lambda v: _is_int(v) and (v >= 1 or v == -1)),
    "optimize_memory_usage": _BOOL,
}
# The rule of each algorithm key that takes a plain value (classes and objects such as
# replay_buffer_class are left to stable-baselines3, whose refusal is one line too).
ALGORITHM_RULES: dict[str, dict[str, Rule]] = {
    "ppo": {
        **_COMMON_RULES,
        "n_epochs": _int_from(1),
        "gae_lambda": _UNIT,
        "clip_range": _POSITIVE,
        "clip_range_vf": _optional(_POSITIVE),
        "normalize_advantage": _BOOL,
        "ent_coef": _NONNEGATIVE,
        "vf_coef": _NONNEGATIVE,
        "max_grad_norm": _POSITIVE,
        "target_kl": _optional(_POSITIVE),
    },
    "sac": {
        **_COMMON_RULES,
        **_OFF_POLICY_RULES,
        "ent_coef": Rule("auto, auto_<number > 0> or a finite number >= 0", _sac_ent_coef),
        "target_update_interval": _int_from(1),
        "target_entropy": Rule("auto or a finite number", lambda v: v == "auto" or _is_real(v)),
        "use_sde_at_warmup": _BOOL,
    },
    "td3": {
        **_COMMON_RULES,
        **_OFF_POLICY_RULES,
        "policy_delay": _int_from(1),
        "target_policy_noise": _NONNEGATIVE,
        "target_noise_clip": _NONNEGATIVE,
    },
}
# VecNormalize's options (the training key normalize), and their rules.
NORMALIZE_RULES = {
    "norm_obs": _BOOL,
    "norm_reward": _BOOL,
    "clip_obs": _POSITIVE,
    "clip_reward": _POSITIVE,
    "gamma": _UNIT,
    "epsilon": _POSITIVE,
    "norm_obs_keys": Rule(
        "null or a list of observation keys",
        lambda v: v is None or (isinstance(v, list) and all(isinstance(k, str) for k in v)),
    ),
}


def check_algorithm_values(params: Mapping[str, Any], algo: str) -> None:
    """ValueError for a value outside its key's rule (:data:`ALGORITHM_RULES` for
    ``algo``'s keys, :data:`NORMALIZE_RULES` for ``normalize``'s), naming the key, what it
    may be and the value; for PPO with ``normalize_advantage`` (its default), also a
    ``batch_size`` of 1 or a rollout (``n_steps`` x ``n_envs``) of one step, which it
    cannot normalise. Keys without a rule are left to the constructor."""
    for key, rule in ALGORITHM_RULES.get(algo, {}).items():
        if key in params and not rule.check(params[key]):
            raise ValueError(f"hyperparameter {key} must be {rule.allowed}, got {params[key]!r}")
    normalize = params.get("normalize")
    if isinstance(normalize, Mapping):
        for key, value in normalize.items():
            if key not in NORMALIZE_RULES:
                raise ValueError(
                    f"unknown hyperparameter normalize.{key}; VecNormalize's options are "
                    f"{', '.join(NORMALIZE_RULES)}"
                )
            rule = NORMALIZE_RULES[key]
            if not rule.check(value):
                raise ValueError(
                    f"hyperparameter normalize.{key} must be {rule.allowed}, got {value!r}"
                )
    if algo == "ppo" and params.get("normalize_advantage", True):
        if params.get("batch_size", 64) < 2:
            raise ValueError(
                "hyperparameter batch_size must be >= 2 with normalize_advantage (PPO "
                "normalises each minibatch's advantages), got 1; or set "
                "normalize_advantage=False"
            )
        rollout = params.get("n_steps", 2048) * int(params.get("n_envs", 1))
        if rollout < 2:
            raise ValueError(
                "hyperparameter n_steps x n_envs must be >= 2 with normalize_advantage "
                f"(a rollout of one step has no advantages to normalise), got {rollout}"
            )


def split(params: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(training keys, algorithm constructor keys) of resolved ``params``."""
    training = {k: v for k, v in params.items() if k in TRAINING_DEFAULTS}
    algo_kwargs = {k: v for k, v in params.items() if k not in TRAINING_DEFAULTS}
    for key in INTEGER_KEYS:
        training[key] = int(training[key])
    return training, algo_kwargs


def build_algo_kwargs(algo_kwargs: Mapping[str, Any], action_dim: int) -> dict[str, Any]:
    """``algo_kwargs`` with the text values built: the activation function's class and
    the action-noise object."""
    import torch.nn
    from stable_baselines3.common.noise import NormalActionNoise

    built = copy.deepcopy(dict(algo_kwargs))
    policy_kwargs = built.get("policy_kwargs") or {}
    if "activation_fn" in policy_kwargs:
        names = {"relu": torch.nn.ReLU, "tanh": torch.nn.Tanh, "elu": torch.nn.ELU}
        policy_kwargs["activation_fn"] = names[policy_kwargs["activation_fn"]]
    if "action_noise" in built:
        sigma = float(built["action_noise"]["sigma"])
        built["action_noise"] = NormalActionNoise(
            mean=np.zeros(action_dim), sigma=np.full(action_dim, sigma)
        )
    return built
