"""``observer-gym study delay-rl``: does an agent need an observer under random delays?

PPO agents of one recipe read, at each delay level, the newest measurement, a stack of
the last few with their ages, a latency-aware filter's belief, the same filter without
latency handling, or the true state (on BallTable also the last camera frames, trained at
the moderate level only); the agents trained at the moderate level are also evaluated at
the others. :mod:`.plan` names the levels and inputs, :mod:`.delivery`
measures how a level's frames arrive, :mod:`.run` runs a study into its folder
(resumably) and :mod:`.table` derives its table from the per-seed records.
"""

from observer_gym.train.experiments.delay_rl.plan import (
    LEVELS,
    SHIFT_FROM,
    AgentInput,
    DelayLevel,
    StudyPlan,
    inputs_for,
)
from observer_gym.train.experiments.delay_rl.run import StudyResult, run_study
from observer_gym.train.experiments.delay_rl.table import StudyTable, check_table, derive_table

__all__ = [
    "LEVELS",
    "SHIFT_FROM",
    "AgentInput",
    "DelayLevel",
    "StudyPlan",
    "StudyResult",
    "StudyTable",
    "check_table",
    "derive_table",
    "inputs_for",
    "run_study",
]
