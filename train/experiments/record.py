"""``observer-gym record``: closed-loop episodes of one observer and controller kept as a
Minari dataset (:mod:`observer_gym.train.reports.dataset`).

The episodes run as :func:`~observer_gym.train.experiments.episode.run_episode_here` runs
them (the same env, controller and loop; episode i resets with ``seed + i``), with Minari's
DataCollector between the observer env and the controller
(:func:`~observer_gym.train.reports.dataset.recording_env`): the dataset's observations
are what the observer was given (frames, measurements, or the state for ``oracle``), its
actions what reached the env (after a trained agent's own wrappers), its infos hold the
truth and the observer's estimate. One env serves all the episodes, each reset with its
seed; with a randomisation (``record --randomize``) each episode's world is rebuilt with
the options it draws (:class:`~observer_gym.train.rl.randomize.RandomizedEnv` beneath the
collector). :func:`record_played` records a trainer's own player the same way (the
learned observers' training data).
"""

from __future__ import annotations

import dataclasses
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from observer_gym.extras import require_record
from observer_gym.train.core import entries
from observer_gym.train.core.observer_env import with_observer_env_options
from observer_gym.train.experiments.episode import (
    EpisodeError,
    build_controller,
    describe_controller,
)
from observer_gym.train.experiments.request import check_pair, resolve_request
from observer_gym.train.reports.outputs import (
    VERSIONED_PACKAGES,
    package_versions,
    to_jsonable,
    write_json_atomic,
)
from observer_gym.train.reports.progress import progress_bar
from observer_gym.train.rl.randomize import (
    RandomizedEnv,
    check_randomize,
    end_values,
    union_space,
)


def check_new_folder(out_dir: str | Path) -> Path:
    """``out_dir`` as a Path; ValueError if it exists (a recording is written whole into a
    new folder, never over another)."""
    out_dir = Path(out_dir)
    if out_dir.exists() or out_dir.is_symlink():
        raise ValueError(f"{out_dir} exists; record writes a new folder: give one that does not")
    return out_dir


def record_experiment(
    env_id: str,
    observer: str,
    controller: str,
    episodes: int,
    seed: int,
    out_dir: str | Path,
    steps: int | None = None,
    progress: bool = True,
    env_kwargs: Mapping[str, Any] | None = None,
    reset_options: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
    cli_args: Mapping[str, Any] | None = None,
    randomize: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Run ``episodes`` closed-loop episodes and keep them as a Minari dataset in the new
    folder ``out_dir``.

    Episode i resets with ``seed + i`` (and ``reset_options``) and runs to the env's end or
    ``steps`` steps. With ``randomize`` (env option -> ``{"low": LOW, "high": HIGH}`` or
    ``{"choices": [...]}``, :mod:`observer_gym.train.rl.randomize`'s forms) each episode
    instead draws its options and then its world's seed from one generator seeded with
    ``seed``, as the learned observers' collections draw theirs
    (:data:`WORLD_SEEDS_BELOW`), and its world is rebuilt with them (the controller, unless
    a trained agent, designed anew on it); each episode's metadata holds its world's
    ``seed`` and its ``drawn_options``, and ``record.json``'s episodes the same.

    ``out_dir`` then holds the dataset, ``observer_gym/SYSTEM-OBSERVER-
    CONTROLLER-v0/data`` (:func:`~observer_gym.train.reports.dataset.dataset_id_for`; load
    it with ``minari.load_dataset(ID)`` and ``MINARI_DATASETS_PATH=out_dir``, or
    :func:`~observer_gym.train.reports.dataset.load_recording`), and ``record.json``
    (``dataset_id``, ``config``, ``versions``, ``episodes``: seed and steps of each). The
    dataset's metadata holds the same under ``observer_gym``. The folder appears whole at
    the end or not at all (:func:`~observer_gym.train.reports.dataset.staged_datasets`).

    Returns:
        What ``record.json`` holds.

    Raises:
        ExtraNotInstalled: minari (the ``[record]`` extra) is not installed.
        ValueError: an unknown env, observer or controller, a count < 1, a negative seed,
            a randomisation the env refuses (naming the option and what is allowed), or
            ``out_dir`` exists.
        EpisodeError: an episode failed part-way (nothing is written).
    """
    require_record()
    env_id = check_pair(env_id, observer, controller)
    for name, value in (("episodes", episodes), ("steps", steps)):
        if value is not None and (int(value) != value or value < 1):
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    out_dir = check_new_folder(out_dir)
    request = resolve_request(
        env_id, [observer], [controller], range(seed, seed + episodes), 1, "local", None,
        steps, dict(env_kwargs or {}), observer_options, controller_options,
    )  # fmt: skip
    observer_entry, controller_entry = request.observers[0], request.controllers[0]
    system = request.system
    gym_options = request.env_kwargs_for(controller_entry)
    checked = check_randomize(
        env_id,
        observer_entry.obs_mode,
        with_observer_env_options(observer_entry, gym_options),
        randomize,
        fixed=env_kwargs,
        fixed_by="env_kwargs",
    )

    from observer_gym.train.reports import dataset  # needs minari: after require_record

    dataset_id = dataset.dataset_id_for(system.name, observer, controller)
    per_episode = None if not checked else randomized_worlds(env_id, checked)
    with (
        entries.objects_in_use(entries.objects_for(observer, controller)),
        dataset.staged_datasets(out_dir) as staging,
    ):
        space = recorded_space(system.env_id, observer_entry, gym_options, checked)
        collector = dataset.recording_env(system, observer_entry, gym_options, per_episode, space)
        try:
            world = dataset.world_stack(collector)
            env: Any = world.unwrapped
            spec = fixed_spec(world, checked)
            built = build_controller(controller_entry, world, system)
            redesign = None
            if checked and controller_entry.kind not in ("agent", "policy"):
                redesign = lambda: build_controller(  # noqa: E731
                    controller_entry, dataset.world_stack(collector), system
                )
            played = _play(
                built, collector, request.seeds, steps, reset_options, progress, redesign
            )
            observed = observer_entry.record()
            record = to_jsonable(
                {
                    "dataset_id": dataset_id,
                    "config": {
                        "env_id": env_id,
                        "env_kwargs": {"obs_mode": observed["obs_mode"], **gym_options},
                        # randomised: each episode's drawn_options over env_kwargs
                        "env_config": None if checked else dataclasses.asdict(env.config),
                        "observer": observer,
                        **{k: v for k, v in observed.items() if k != "obs_mode"},
                        "observer_options": observer_entry.options,
                        "controller": controller,
                        "controller_config": describe_controller(built),
                        "controller_options": controller_entry.options,
                        "episodes": episodes,
                        "seed": seed,
                        "steps": steps,
                        "reset_options": reset_options,
                        "randomize": checked or None,
                        "out_dir": str(out_dir),
                        "cli_args": cli_args,
                        "command": sys.argv if cli_args is not None else None,
                    },
                    "versions": package_versions((*VERSIONED_PACKAGES, "minari")),
                    "episodes": played,
                }
            )
            write_dataset(
                collector,
                staging,
                record,
                spec,
                algorithm_name=f"observer {observer}, controller {controller}",
                description=(
                    f"{env_id} with observer {observer} and controller {controller}: "
                    f"{episodes} episode(s) from seed {seed}, recorded by observer-gym"
                ),
            )
        finally:
            collector.close()  # closes the env; removes Minari's temporary folder
    return record


# each randomised episode's world seed is drawn uniform in 0..this - 1 after its options,
# as the learned observers' collections draw theirs
WORLD_SEEDS_BELOW = 2**31


def fixed_spec(world: Any, randomize: Mapping[str, Any]) -> Any:
    """The env spec of the recording: ``world``'s (the env of the observations, with its
    obs_mode), without the options ``randomize`` draws (each episode's own)."""
    spec = world.spec
    assert spec is not None  # made with gym.make
    if not randomize:
        return spec
    kept = {k: v for k, v in spec.kwargs.items() if k not in randomize}
    return dataclasses.replace(spec, kwargs=kept)


def randomized_worlds(
    env_id: str, randomize: Mapping[str, Mapping[str, Any]], integers: bool = True
) -> Any:
    """The ``per_episode`` of :func:`~observer_gym.train.reports.dataset.recording_env` for
    a checked randomisation: a :class:`~observer_gym.train.rl.randomize.RandomizedEnv`
    drawing options then world seeds below :data:`WORLD_SEEDS_BELOW` (integer options as
    integers unless ``integers`` is False: every range a float, as the learned observers'
    collections draw)."""

    def per_episode(make_stack: Any) -> RandomizedEnv:
        return RandomizedEnv(
            make_stack,
            env_id,
            randomize,
            world_seeds_below=WORLD_SEEDS_BELOW,
            integers=integers,
            bounds_may_differ=True,
        )

    return per_episode


def recorded_space(
    env_id: str,
    observer: Any,
    env_kwargs: Mapping[str, Any],
    randomize: Mapping[str, Mapping[str, Any]],
) -> Any:
    """The observation space of a randomised recording of ``observer``'s obs mode: the
    union (:func:`~observer_gym.train.rl.randomize.union_space`) of the env's at every
    choice and range end, each varied alone (a draw may widen a bound: TargetFollower's
    pixel bounds grow with ``measurement_noise_px``); None without a randomisation."""
    import gymnasium as gym

    if not randomize:
        return None
    spaces = []
    for drawn in end_values(randomize):
        options = with_observer_env_options(observer, {**env_kwargs, **drawn})
        env = gym.make(env_id, obs_mode=observer.obs_mode, **options)
        try:
            spaces.append(env.observation_space)
        finally:
            env.close()
    return union_space(spaces)


def episode_reset_kwargs(
    index: int, seed: int, randomized: bool, reset_options: Mapping[str, Any] | None
) -> dict[str, Any]:
    """The DataCollector's reset arguments of episode ``index``: ``seed + index``; for a
    randomised recording ``seed`` at the first (seeding the draws) and no seed after (the
    draws go on; Minari told not to seed the reset itself)."""
    from observer_gym.train.reports.dataset import MINARI_AUTOSEED

    if not randomized:
        return {"seed": seed + index, "options": reset_options}
    if index == 0:
        return {"seed": seed, "options": reset_options}
    return {"seed": None, "options": {**(reset_options or {}), MINARI_AUTOSEED: False}}


def write_dataset(
    collector: Any,
    staging: Path,
    record: dict[str, Any],
    spec: Any,
    algorithm_name: str,
    description: str,
) -> None:
    """Write the collector's episodes as the dataset ``record["dataset_id"]`` into
    ``staging`` (inside :func:`~observer_gym.train.reports.dataset.staged_datasets`), with
    ``record`` in its metadata (``observer_gym``) and in ``record.json``; a randomised
    recording's episodes (``world_seed`` and ``drawn_options`` in ``record["episodes"]``)
    get theirs in their episode metadata."""
    from observer_gym.train.reports import dataset

    with warnings.catch_warnings():  # Minari's advice to name an author and a link
        warnings.simplefilter("ignore", UserWarning)
        written = collector.create_dataset(
            dataset_id=record["dataset_id"],
            eval_env=spec,
            algorithm_name=algorithm_name,
            author="observer-gym record",
            description=description,
        )
    written.storage.update_metadata({"observer_gym": record})
    if any("drawn_options" in episode for episode in record["episodes"]):
        dataset.set_drawn_episodes(
            written, [(e["seed"], e["drawn_options"]) for e in record["episodes"]]
        )
    write_json_atomic(staging / dataset.RECORD_FILE, record)


def _play(
    controller: Any,
    env: Any,
    seeds: Sequence[int],
    steps: int | None,
    reset_options: Mapping[str, Any] | None,
    progress: bool,
    redesign: Callable[[], Any] | None = None,
) -> list[dict[str, Any]]:
    """The episodes of ``seeds`` on ``env`` (the DataCollector) as
    :func:`~observer_gym.train.experiments.episode.run_episode_here` plays them; each
    episode's seed, steps and how it ended. A randomised recording (``env`` above a
    RandomizedEnv) resets as :func:`episode_reset_kwargs` says, records each episode's
    world seed and drawn options, and designs the controller anew on each episode's
    world with ``redesign`` (if given)."""
    randomized = env.unwrapped if isinstance(env.unwrapped, RandomizedEnv) else None
    # a trained agent sees the env through its own wrappers; the collector is beneath
    played_env = getattr(controller, "wrap_env", lambda env: env)(env)
    played = []
    with progress_bar(total=len(seeds), unit="episode", desc="record", disable=not progress) as bar:
        for index, seed in enumerate(seeds):
            step = 0
            terminated = truncated = False
            reset_kwargs = episode_reset_kwargs(
                index, seeds[0], randomized is not None, reset_options
            )
            try:
                if redesign is None:
                    controller.reset()
                    obs, info = played_env.reset(**reset_kwargs)
                else:  # a design on the episode's world, which the reset rebuilds
                    obs, info = played_env.reset(**reset_kwargs)
                    controller = redesign()
                    controller.reset()
                observe_info = getattr(controller, "observe_info", lambda info: None)
                observe_info(info)
                while not (terminated or truncated) and (steps is None or step < steps):
                    action, _ = controller.predict(obs)
                    obs, _, terminated, truncated, info = played_env.step(action)
                    observe_info(info)
                    step += 1
            except ValueError as exc:  # an observer's or controller's fault: which, when
                raise EpisodeError(f"{exc} (episode seed {seed}, after {step} steps)") from None
            episode: dict[str, Any] = {
                "seed": seed,
                "steps": step,
                "terminated": terminated,
                "truncated": truncated,
            }
            if randomized is not None:
                assert randomized.world_seed is not None  # reset above
                episode["seed"] = randomized.world_seed
                episode["drawn_options"] = dict(randomized.options)
            played.append(episode)
            bar.update(1)
    return played


# a player of a recording made by a trainer: (the episode's world stack, the generator of
# the draws) -> the episode's policy, (observation, info) -> the action given to the env
Player = Callable[[Any, Any], Callable[[Any, Mapping[str, Any]], Any]]


def record_played(
    env_id: str,
    observer: str,
    out_dir: str | Path,
    *,
    randomize: Mapping[str, Mapping[str, Any]],
    episodes: int,
    seed: int,
    steps: int | None,
    player: Player,
    player_name: str,
    config: Mapping[str, Any],
    env_kwargs: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Record ``episodes`` episodes played by ``player`` (a trainer's collection: a
    controller on the truth with action noise drawn from the same generator as the
    options) as a Minari dataset in the new folder ``out_dir``, as
    :func:`record_experiment` records (``record.json``, metadata, staging) with its
    randomisation: each episode draws ``randomize``'s options (every range a float) and
    then its world's seed from one generator seeded with ``seed``; ``player`` is given the
    episode's world stack and that generator after the reset, and each step's action comes
    from it, up to ``steps`` steps or the env's end. ``observer`` names the observer whose
    env is recorded (its obs mode; its estimate in the infos if it has one); ``config`` is
    kept in the record's ``config`` beside these arguments.

    Returns:
        What ``record.json`` holds.
    """
    require_record()
    from observer_gym.envs import system_for_id
    from observer_gym.train.core.observer_env import resolve_observer
    from observer_gym.train.reports import dataset

    out_dir = check_new_folder(out_dir)
    system = system_for_id(env_id)
    observer_entry = resolve_observer(system, observer)
    gym_options = dict(env_kwargs or {})
    checked = check_randomize(
        system.env_id, observer_entry.obs_mode, gym_options, randomize, fixed=gym_options
    )
    dataset_id = dataset.dataset_id_for(system.name, observer, player_name)
    per_episode = randomized_worlds(system.env_id, checked, integers=False)
    with dataset.staged_datasets(out_dir) as staging:
        space = recorded_space(system.env_id, observer_entry, gym_options, checked)
        collector = dataset.recording_env(system, observer_entry, gym_options, per_episode, space)
        try:
            randomized = collector.unwrapped
            assert isinstance(randomized, RandomizedEnv)
            played = []
            for index in range(episodes):
                obs, info = collector.reset(**episode_reset_kwargs(index, seed, True, None))
                policy = player(dataset.world_stack(collector), randomized.rng)
                step = 0
                terminated = truncated = False
                while not (terminated or truncated) and (steps is None or step < steps):
                    obs, _, terminated, truncated, info = collector.step(policy(obs, info))
                    step += 1
                assert randomized.world_seed is not None  # reset above
                played.append(
                    {
                        "seed": randomized.world_seed,
                        "steps": step,
                        "terminated": terminated,
                        "truncated": truncated,
                        "drawn_options": dict(randomized.options),
                    }
                )
            record = to_jsonable(
                {
                    "dataset_id": dataset_id,
                    "config": {
                        "env_id": system.env_id,
                        "env_kwargs": {"obs_mode": observer_entry.obs_mode, **gym_options},
                        "observer": observer,
                        "player": player_name,
                        **dict(config),
                        "episodes": episodes,
                        "seed": seed,
                        "steps": steps,
                        "randomize": checked,
                        "out_dir": str(out_dir),
                    },
                    "versions": package_versions((*VERSIONED_PACKAGES, "minari")),
                    "episodes": played,
                }
            )
            write_dataset(
                collector,
                staging,
                record,
                fixed_spec(dataset.world_stack(collector), checked),
                algorithm_name=player_name,
                description=(
                    f"{system.env_id}, {player_name}: {episodes} episode(s) with options "
                    f"drawn from seed {seed}, recorded by observer-gym"
                ),
            )
        finally:
            collector.close()
    return record
