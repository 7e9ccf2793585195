"""What the random-delay study trains and evaluates: its delay levels, the agent inputs,
and the plan of one study folder (:class:`StudyPlan`, recorded as ``study.json``).

A delay level is a sensor setting of every camera, in seconds: a latency, a Gaussian
jitter of each frame's latency (so frames can arrive out of capture order) and a
probability that a frame is never delivered (:class:`DelayLevel`). An input is what a
PPO agent reads (:class:`AgentInput`): the newest measurement alone, a stack of the last
:data:`STACK_K` measurements with their ages, the latency-aware filter's belief, the
same filter without latency handling, or the true state; on BallTable also the last
camera frames (``train --obs rgb``, the system's tuned pixel recipe), trained at the
:data:`SHIFT_FROM` level only and evaluated at every level.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

from observer_gym.envs import system_for_id
from observer_gym.train.core.checks import check_seeds


class DelayLevel(NamedTuple):
    """One delay setting of every camera (``gym.make`` options, in seconds)."""

    name: str
    latency_s: float  # from a frame's capture to its delivery
    latency_jitter_s: float  # std of a Gaussian added to each frame's latency (kept >= 0)
    frame_drop_prob: float  # probability a captured frame is never delivered

    def env_kwargs(self) -> dict[str, float]:
        """The env options of this level."""
        return {
            "latency_s": self.latency_s,
            "latency_jitter_s": self.latency_jitter_s,
            "frame_drop_prob": self.frame_drop_prob,
        }


# At 50 frames/s (20 ms apart) a jitter of 30 ms lets a frame overtake the one before it
# about a quarter of the time (measured: out_of_order.json of a study folder).
LEVELS: dict[str, DelayLevel] = {
    "none": DelayLevel("none", 0.0, 0.0, 0.0),
    "moderate": DelayLevel("moderate", 0.04, 0.01, 0.05),
    "heavy": DelayLevel("heavy", 0.10, 0.03, 0.20),
}
# the level whose agents are also evaluated at every other level (the shift)
SHIFT_FROM = "moderate"
STACK_K = 4  # measurements in the "stack" input
PIXEL_FRAMES = 4  # frames in the "pixels" input: the tuned rgb recipe's frame_stack
# system name -> the classical controller whose runs on each belief are the reference lines
REFERENCE_CONTROLLERS = {"ball_table": "lqr", "ball_catcher": "intercept", "target_follower": "vtc"}


class AgentInput(NamedTuple):
    """What one agent of the study reads: the ``observer-gym train`` settings."""

    name: str
    obs: str  # measurements, estimate or state
    observer: str | None  # the estimating observer (obs "estimate")
    hyperparams: Mapping[str, Any]  # over the system's tuned PPO hyperparameters
    reference_observer: str | None  # the classical controller's reference line reads this
    delay_free: bool  # the delay does not reach it (the true state): trained once
    summary: str
    # the one level it trains at (evaluated at every level when that is SHIFT_FROM);
    # None: it trains at every level of the plan
    trained_only_at: str | None = None

    def setting(self) -> dict[str, Any]:
        """The input as JSON types, as ``study.json`` records it (``trained_only_at`` only
        when set, so the plans recorded before it existed still load)."""
        data = {**self._asdict(), "hyperparams": dict(self.hyperparams)}
        if self.trained_only_at is None:
            del data["trained_only_at"]
        return data


# system name -> (the latency-aware filter, the same filter fusing at delivery, the
# features a belief is read through: None keeps the tuned recipe's)
_FILTERS: dict[str, tuple[str, str, str | None]] = {
    "ball_table": ("kf-latency-measurements", "kf-measurements", "belief"),
    # the tuned recipe reads the belief through the crossing features (they hold the
    # predicted miss's standard deviation)
    "ball_catcher": ("kf-latency-measurements", "kf-at-delivery-measurements", None),
    "target_follower": ("kf-latency-measurements", "kf-measurements", None),
}


def inputs_for(env_id: str) -> dict[str, AgentInput]:
    """The study's inputs on ``env_id``'s system, by name, in the table's order."""
    system = system_for_id(env_id)
    if system.name not in _FILTERS:
        raise ValueError(
            f"the delay-rl study has no inputs for {system.short_id}; it runs on "
            + ", ".join(system_for_id(name).short_id for name in _study_env_ids())
        )
    latency_aware, at_delivery, features = _FILTERS[system.name]
    belief = {} if features is None else {"features": features}
    return {
        "newest": AgentInput(
            "newest",
            "measurements",
            None,
            {"measurement_stack": 1},
            None,
            False,
            "the newest measurement alone, with its age",
        ),
        "stack": AgentInput(
            "stack",
            "measurements",
            None,
            {"measurement_stack": STACK_K},
            None,
            False,
            f"the last {STACK_K} measurements with their ages",
        ),
        "kf-latency": AgentInput(
            "kf-latency",
            "estimate",
            latency_aware,
            belief,
            latency_aware,
            False,
            f"the latency-aware filter's belief, mean and covariance ({latency_aware})",
        ),
        "kf": AgentInput(
            "kf",
            "estimate",
            at_delivery,
            belief,
            at_delivery,
            False,
            f"the same filter without latency handling ({at_delivery})",
        ),
        "truth": AgentInput(
            "truth", "state", None, belief, "oracle", True, "the true state (upper line)"
        ),
        **_pixel_inputs(system.name),
    }


# systems whose study also has the pixel input (the tuned ``rgb`` recipe of ppo.yml)
PIXEL_SYSTEMS = ("ball_table",)


def _pixel_inputs(system_name: str) -> dict[str, AgentInput]:
    """The ``pixels`` input where the study has one: the agent reads what ``train --obs
    rgb`` gives it (the system's tuned image options: the newest delivered frame of each
    step, resized, read by the system's frozen frame encoder, the last few stacked), at
    the moderate level only."""
    if system_name not in PIXEL_SYSTEMS:
        return {}
    return {
        "pixels": AgentInput(
            "pixels",
            "rgb",
            None,
            {},
            None,
            False,
            f"the last {PIXEL_FRAMES} camera frames (84 x 84, the {system_name} frame encoder)",
            trained_only_at=SHIFT_FROM,
        )
    }


def _study_env_ids() -> list[str]:
    from observer_gym.envs import SYSTEMS

    return [system.env_id for system in SYSTEMS if system.name in _FILTERS]


@dataclasses.dataclass(frozen=True)
class StudyPlan:
    """One study folder's plan (``study.json``): one system, the levels and inputs, the
    seeds and the budget. Every input trains with the same PPO recipe (the system's tuned
    hyperparameters, ``timesteps`` env steps per seed)."""

    env_id: str
    levels: tuple[str, ...]
    inputs: tuple[str, ...]
    seeds: tuple[int, ...]
    timesteps: int
    eval_episodes: int
    eval_seed: int = 1_000_000  # evaluation episode i resets with eval_seed + i
    algo: str = "ppo"
    # the learning curve: this many evaluations of this many episodes during training
    # (they do not change what is learned)
    curve_points: int = 4
    curve_episodes: int = 5

    def __post_init__(self) -> None:
        object.__setattr__(self, "env_id", system_for_id(self.env_id).env_id)
        allowed = inputs_for(self.env_id)
        _check_names("level", self.levels, LEVELS)
        _check_names("input", self.inputs, allowed)
        for name in self.inputs:
            only_at = allowed[name].trained_only_at
            if only_at is not None and only_at not in self.levels:
                raise ValueError(
                    f"input {name!r} trains at the {only_at} level only: add {only_at} to "
                    f"the levels (got {', '.join(self.levels)})"
                )
        object.__setattr__(self, "seeds", check_seeds(self.seeds))
        for name in ("timesteps", "eval_episodes", "curve_points", "curve_episodes"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")

    @property
    def level_records(self) -> dict[str, DelayLevel]:
        return {name: LEVELS[name] for name in self.levels}

    @property
    def input_records(self) -> dict[str, AgentInput]:
        allowed = inputs_for(self.env_id)
        return {name: allowed[name] for name in self.inputs}

    @property
    def curve_hyperparams(self) -> dict[str, int]:
        """The evaluation settings of the learning curve (the same for every input)."""
        return {
            "eval_freq": max(self.timesteps // self.curve_points, 1),
            "eval_episodes": self.curve_episodes,
        }

    def train_cells(self) -> list[tuple[str, str]]:
        """(level, input) of every multi-seed training: each input at each level, but an
        input the delay does not reach once, at the first level, and an input trained at
        one level only (``trained_only_at``) at that level."""
        return [
            (level, name)
            for level in self.levels
            for name in self.inputs
            if self.trained_at(level, name) == level
        ]

    def trained_at(self, level: str, name: str) -> str | None:
        """The level the agents that stand for input ``name`` at ``level`` (the table's
        cell) trained at; None if no agents of that input train for that level."""
        agent_input = self.input_records[name]
        if agent_input.delay_free:
            return self.levels[0]
        if agent_input.trained_only_at is not None and agent_input.trained_only_at != level:
            return None
        return level

    def eval_cells(self) -> list[tuple[str, str, str]]:
        """(trained at, input, evaluated at) of every evaluation: each agent at its own
        level; the agents of :data:`SHIFT_FROM` and the delay-free ones at every level."""
        cells = []
        for level, name in self.train_cells():
            shifted = level == SHIFT_FROM or self.input_records[name].delay_free
            for at in self.levels if shifted else (level,):
                cells.append((level, name, at))
        return cells

    def extends(self, held: StudyPlan) -> bool:
        """Whether this plan is ``held`` with inputs added and nothing else changed: a
        folder of ``held`` continues as this plan, training only the added inputs."""
        return (
            set(held.inputs) < set(self.inputs)
            and dataclasses.replace(self, inputs=held.inputs) == held
        )

    def as_dict(self) -> dict[str, Any]:
        """The plan as JSON types, with each level's values and each input's settings."""
        return {
            **dataclasses.asdict(self),
            "levels": list(self.levels),
            "inputs": list(self.inputs),
            "seeds": list(self.seeds),
            "level_values": {n: level._asdict() for n, level in self.level_records.items()},
            "input_settings": {n: i.setting() for n, i in self.input_records.items()},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> StudyPlan:
        """The plan a ``study.json`` records; ValueError if it is not one or if the
        levels or inputs it records differ from this version's."""
        try:
            plan = cls(
                env_id=data["env_id"],
                levels=tuple(data["levels"]),
                inputs=tuple(data["inputs"]),
                seeds=tuple(data["seeds"]),
                timesteps=data["timesteps"],
                eval_episodes=data["eval_episodes"],
                eval_seed=data["eval_seed"],
                algo=data["algo"],
                curve_points=data["curve_points"],
                curve_episodes=data["curve_episodes"],
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"not a delay-rl study's plan: {exc!r}") from None
        recorded = {k: data.get(k) for k in ("level_values", "input_settings")}
        if recorded != {k: plan.as_dict()[k] for k in recorded}:
            raise ValueError(
                "the study was planned with other delay levels or input settings than this "
                "version of observer-gym has; run it into a new folder"
            )
        return plan


def _check_names(kind: str, names: Sequence[str], allowed: Mapping[str, Any]) -> None:
    if not names:
        raise ValueError(f"a study needs at least one {kind}; allowed: {', '.join(allowed)}")
    unknown = [name for name in names if name not in allowed]
    if unknown:
        raise ValueError(f"unknown {kind} {unknown[0]!r}; allowed: {', '.join(allowed)}")
    if len(set(names)) != len(names):
        raise ValueError(f"each {kind} once, got {', '.join(names)}")
