"""``python -m observer_gym.train.cli``: the ``observer-gym`` command."""

from observer_gym.train.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
