"""The schedule the training callbacks share: act every ``every_steps`` env steps."""

from __future__ import annotations

from observer_gym.extras import require_rl

# training imports this first: without the [rl] extra, the error names its install line
require_rl("training an agent (observer_gym.train.rl)")
from stable_baselines3.common.callbacks import BaseCallback  # noqa: E402


class EveryStepsCallback(BaseCallback):
    """Calls :meth:`act` at the first callback step at or past each multiple of
    ``every_steps`` env steps (the count moves by ``n_envs`` per vector step, and a
    resumed run starts from its checkpoint's count)."""

    def __init__(self, every_steps: int) -> None:
        super().__init__()
        self.every_steps = int(every_steps)
        self._next: int | None = None

    def _schedule(self) -> None:
        self._next = (self.num_timesteps // self.every_steps + 1) * self.every_steps

    def _on_training_start(self) -> None:
        self._schedule()

    def _on_step(self) -> bool:
        assert self._next is not None  # scheduled at the training's start
        if self.num_timesteps >= self._next:
            self.act()
            self._schedule()
        return True

    def act(self) -> None:
        raise NotImplementedError
