"""``observer-gym list``: the systems, observers, controllers and shipped agents, one line each."""

from __future__ import annotations

import argparse

from observer_gym.extras import AGENT_MODULES, RL_INSTALL, missing_modules
from observer_gym.train.cli.args import Command

LIST_KINDS = ("system", "observer", "controller", "agent")
RL_MARK = "[rl]"  # after an entry that needs the [rl] extra (observer_gym.extras)


def _list_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "kind",
        nargs="?",
        choices=LIST_KINDS,
        default=None,
        help="list only these (default: everything)",
    )


def _list_run(args: argparse.Namespace) -> int:
    from observer_gym.train.experiments.catalogue import catalogue  # deferred: reads every layer

    items = [item for item in catalogue() if args.kind in (None, item.kind)]
    for kind in LIST_KINDS:
        group = [item for item in items if item.kind == kind]
        if not group:
            continue
        print(f"{kind}s:")
        width = max(len(item.name) for item in group)
        for item in group:
            where = ", ".join(env_id.split("/", 1)[-1] for env_id in item.systems)
            where = "" if kind == "system" else f" ({where})"
            source = "" if item.source == "observer-gym" else f" [{item.source}]"
            rl = f" {RL_MARK}" if item.needs_rl else ""
            print(f"  {item.name:<{width}}  {item.summary}{where}{rl}{source}")
    if any(item.needs_rl for item in items):
        installed = "installed" if not missing_modules(AGENT_MODULES) else "not installed"
        print(f"{RL_MARK}: needs PyTorch and stable-baselines3 ({installed}): {RL_INSTALL}")
    return 0


COMMAND = Command(
    help="list the systems, observers, controllers and shipped agents, one line each",
    description=(
        "List what the commands take by name: every system (env), observer, controller "
        "and shipped agent, with one line each and the envs it applies to, and the "
        "observers and controllers that installed packages add through the entry-point "
        "groups observer_gym.observers and observer_gym.controllers. Any other observer "
        "or controller is named by import path, package.module:factory. Entries marked "
        "[rl] need the rl extra (PyTorch, stable-baselines3): pip install "
        "'observer-gym[rl]'."
    ),
    add_arguments=_list_arguments,
    run=_list_run,
)
