"""The experiments as Python functions: what the ``observer-gym`` command runs.

``observer_gym.run``, ``compare``, ``sweep`` and ``evaluate`` are these functions; the
command line parses its arguments, calls them and prints their ``text``
(``observer_gym.record`` keeps episodes as a Minari dataset, ``observer-gym record``). Wherever they
take an observer or a controller, it may be

- a name of the package (``"kf"``, ``"lqr"``, ``"ppo:ball_table-estimate"``), a
  stable-baselines3 zip (``"ppo:path/model.zip"``), an import path
  (``"mylab.filters:make_observer"``) or an installed entry point's name
  (:mod:`observer_gym.train.core.entries`), or
- the factory itself, ``factory(env, **options)``, or an object with the protocol (an
  observer pipeline with ``reset()`` and ``observe(obs, info, action) -> Estimate``, a
  controller with stable-baselines3's ``predict``; each episode gets a deep copy). An
  observer given so reads camera frames, or the measurements if it has the attribute
  ``obs_mode = "measurements"``. With ``workers`` > 1 or the Ray backend it must pickle
  (a module-level function or class does; a lambda does not): ValueError before
  anything runs otherwise.

Which episodes run is said the same way in all four: ``episodes=N`` from ``seed=S``
(episode i resets with S + i; default 10 episodes from seed 0), or ``seeds=[...]``, one
episode each. Both may be given when they agree (``len(seeds) == episodes``,
``seeds[0] == seed``); ValueError otherwise. ``compare`` takes any list of seeds; ``run``,
``sweep`` and ``evaluate`` record their episodes as a first seed and a count (results.json,
the sweep's plan and command line), so their ``seeds`` are consecutive (``range(3, 8)``).

Example::

    import observer_gym

    result = observer_gym.compare(
        "BallTable-v0",
        observers=["kf-measurements", "mylab.filters:make_observer-measurements"],
        controllers=["lqr"],
        seeds=range(5),
        out_dir="runs/mine",
    )
    print(result.text)
    for pair in result.pairs:
        print(pair.observer, pair.statistics["mean_distance_m"]["mean"])
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from observer_gym.train.core import entries

Entry = Any  # a name, an import path, a factory or an object (see the module docstring)


class RunResult(NamedTuple):
    """What :func:`run` (and :func:`evaluate`) did."""

    out_dir: Path
    summary: dict[str, Any]  # the task's summary over the episodes
    episodes: list[dict[str, Any]]  # per episode: seed, the task's metrics, NEES/NIS
    consistency: dict[str, Any]  # NEES/dof over the episodes and its chi-square band
    files: list[str]  # written into out_dir
    text: str  # what 'observer-gym run' (or 'evaluate') prints
    results: dict[str, Any]  # all of results.json


class PairResult(NamedTuple):
    """One (observer, controller) pair of a comparison."""

    observer: str
    controller: str
    summary: dict[str, Any]
    statistics: dict[str, Any]  # per compared metric: mean, 95 % interval, n
    consistency: dict[str, Any]
    episodes: list[dict[str, Any]]
    vs_oracle: dict[str, Any] | None  # the paired difference from the oracle, if it ran


class ComparisonResult(NamedTuple):
    """What :func:`compare` did."""

    out_dir: Path
    pairs: list[PairResult]
    files: list[str]
    text: str  # what 'observer-gym compare' prints (the table among it)
    results: dict[str, Any]


class SweepOutcome(NamedTuple):
    """What :func:`sweep` did."""

    out_dir: Path
    cells: list[dict[str, Any]]  # per cell: point, observer, controller, statistics, ...
    cells_run: int
    cells_reused: int
    files: list[str]
    text: str  # what 'observer-gym sweep' prints
    results: dict[str, Any]


class RecordResult(NamedTuple):
    """What :func:`record` did."""

    out_dir: Path  # holds the Minari dataset and record.json
    dataset_id: str  # minari.load_dataset(dataset_id) with MINARI_DATASETS_PATH=out_dir
    episodes: list[dict[str, Any]]  # per episode: seed, steps, terminated, truncated
    record: dict[str, Any]  # all of record.json


class _Entries(NamedTuple):
    observers: list[str]
    controllers: list[str]
    objects: dict[tuple[str, str], Any]


def _names(
    observers: Sequence[Entry], controllers: Sequence[Entry], workers: int, backend: str
) -> _Entries:
    """Names for the entries (:func:`observer_gym.train.core.entries.as_name`) and the
    objects
    among them; ValueError for one that cannot reach the workers."""
    objects: dict[tuple[str, str], Any] = {}
    named: list[list[str]] = [[], []]
    for kind, given, out in (
        ("observer", observers, named[0]),
        ("controller", controllers, named[1]),
    ):
        for entry in given:
            obs_mode = getattr(entry, "obs_mode", "rgb")
            name, found = entries.as_name(kind, entry, obs_mode)
            out.append(name)
            objects.update(found)
    if objects and (workers != 1 or backend != "local"):
        entries.check_picklable(objects)
    return _Entries(named[0], named[1], objects)


def _listed(value: Entry | Sequence[Entry]) -> list[Entry]:
    """A list of entries: a text is split at commas, one object is a list of one."""
    if isinstance(value, str):
        return [part.strip() for part in value.split(",")]
    if isinstance(value, Sequence):
        return list(value)
    return [value]


DEFAULT_EPISODES = 10
DEFAULT_SEED = 0


def episode_seeds(
    episodes: int | None,
    seed: int | None,
    seeds: Sequence[int] | None,
    *,
    consecutive: bool = False,
) -> list[int]:
    """The seeds of the episodes that ``episodes``, ``seed`` and ``seeds`` ask for (the
    module docstring): ``seeds`` as given, else ``episodes`` seeds from ``seed`` (defaults
    10 and 0). ``consecutive``: the seeds must be ``seed``, ``seed + 1``, ...

    Raises:
        ValueError: ``seeds`` empty or not integers >= 0; ``episodes`` or ``seed`` given
            with ``seeds`` and disagreeing with them; ``consecutive`` and the seeds are not.
    """
    if seeds is None:
        first = DEFAULT_SEED if seed is None else seed
        count = DEFAULT_EPISODES if episodes is None else episodes
        for name, value, low in (("episodes", count, 1), ("seed", first, 0)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        return list(range(first, first + count))
    if isinstance(seeds, str | bytes) or not isinstance(seeds, Sequence | range):
        raise ValueError(f"seeds must be a sequence of integers >= 0, got {seeds!r}")
    listed = list(seeds)
    if not listed:
        raise ValueError("seeds must hold at least one seed")
    for value in listed:
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ValueError(f"seeds must be integers >= 0, got {value!r} in {seeds!r}")
    if episodes is not None and episodes != len(listed):
        raise ValueError(
            f"episodes={episodes!r} and seeds={seeds!r} disagree: seeds runs one episode per "
            f"seed ({len(listed)}); give one of them"
        )
    if seed is not None and seed != listed[0]:
        raise ValueError(
            f"seed={seed!r} and seeds={seeds!r} disagree: seed is the first seed "
            f"({listed[0]}); give one of them"
        )
    if consecutive and listed != list(range(listed[0], listed[0] + len(listed))):
        raise ValueError(
            f"seeds={seeds!r}: this experiment runs consecutive seeds (episodes from a first "
            "seed, e.g. range(3, 8)); compare takes any list of seeds"
        )
    return listed


def _out_dir(out_dir: str | Path | None, command: str) -> Path:
    """``out_dir``, or a new folder under the default place for ``command``."""
    from observer_gym.train.reports.outputs import default_out_dir

    return Path(out_dir) if out_dir is not None else default_out_dir(command)


def run(
    env: str,
    observer: Entry,
    controller: Entry,
    *,
    episodes: int | None = None,
    seed: int | None = None,
    seeds: Sequence[int] | None = None,
    out_dir: str | Path | None = None,
    steps: int | None = None,
    workers: int = 1,
    env_options: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
    progress: bool = False,
    cli_args: Mapping[str, Any] | None = None,
    video_dir: str | Path | None = None,
    video_episodes: Sequence[int] | None = None,
    rerun_file: str | Path | None = None,
    rerun_episode: int | None = None,
) -> RunResult:
    """Closed-loop episodes of ``controller`` on ``observer``'s estimate in ``env``
    (:func:`observer_gym.train.experiments.run.run_experiment`): episode i resets with
    ``seed + i`` (or ``seeds``, consecutive: the module docstring); writes results.json
    and the env's plots into ``out_dir`` (default: a new folder under runs/).
    ``observer_options`` and ``controller_options`` go to an outside observer's and
    controller's factory. ``video_dir`` and ``video_episodes``: MP4s of episodes
    (docs/watch.md); ``rerun_file``: a ``.rrd`` recording of episode ``rerun_episode``
    (default 0) for the rerun viewer. ValueError for a bad input, before anything
    runs; :class:`observer_gym.train.experiments.episode.EpisodeError` for an episode that fails
    part-way (nothing is written).

    Example:
        >>> import tempfile
        >>> import observer_gym
        >>> with tempfile.TemporaryDirectory() as out:
        ...     result = observer_gym.run("BallTable-v0", "kf-measurements", "lqr",
        ...                               episodes=2, steps=150, out_dir=out)
        >>> result.summary["fraction_settled"]  # both balls within 1 cm of the centre in 3 s
        1.0
        >>> bool(result.summary["position_rmse_m"] < 1e-3)  # the estimate's error
        True
        >>> sorted(result.files)
        ['error.png', 'estimate.png', 'path.png', 'results.json']
    """
    from observer_gym.train.experiments.run import results_text, run_experiment

    listed = episode_seeds(episodes, seed, seeds, consecutive=True)
    found = _names([observer], [controller], workers, "local")
    folder = _out_dir(out_dir, "run")
    with entries.objects_in_use(found.objects):
        results = run_experiment(
            env_id=env,
            observer=found.observers[0],
            controller=found.controllers[0],
            episodes=len(listed),
            seed=listed[0],
            out_dir=folder,
            steps=steps,
            workers=workers,
            progress=progress,
            env_kwargs=env_options,
            cli_args=cli_args,
            observer_options=observer_options,
            controller_options=controller_options,
            video_dir=video_dir,
            video_episodes=video_episodes,
            rerun_file=rerun_file,
            rerun_episode=rerun_episode,
        )
    return _run_result(results, results_text(results))


def _run_result(results: dict[str, Any], text: str) -> RunResult:
    return RunResult(
        Path(results["config"]["out_dir"]),
        results["summary"],
        results["episodes"],
        results["consistency"],
        results["files"],
        text,
        results,
    )


def record(
    env: str,
    observer: Entry,
    controller: Entry,
    *,
    out_dir: str | Path,
    episodes: int | None = None,
    seed: int | None = None,
    seeds: Sequence[int] | None = None,
    steps: int | None = None,
    env_options: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
    progress: bool = False,
    cli_args: Mapping[str, Any] | None = None,
    randomize: Mapping[str, Any] | None = None,
) -> RecordResult:
    """Closed-loop episodes of ``controller`` on ``observer``'s estimate in ``env`` kept as
    a Minari dataset in the new folder ``out_dir``
    (:func:`observer_gym.train.experiments.record.record_experiment`; docs/record.md):
    episode i resets with ``seed + i`` (or ``seeds``, consecutive); with ``randomize``
    (option -> ``{"low": LOW, "high": HIGH}`` or ``{"choices": [...]}``) each episode
    draws those options and its world's seed from ``seed`` instead. Needs the ``[record]``
    extra (:class:`~observer_gym.extras.ExtraNotInstalled` otherwise); ValueError for a bad
    input or an ``out_dir`` that exists, before anything runs."""
    from observer_gym.train.experiments.record import record_experiment

    listed = episode_seeds(episodes, seed, seeds, consecutive=True)
    found = _names([observer], [controller], 1, "local")
    with entries.objects_in_use(found.objects):
        written = record_experiment(
            env,
            found.observers[0],
            found.controllers[0],
            episodes=len(listed),
            seed=listed[0],
            out_dir=out_dir,
            steps=steps,
            progress=progress,
            env_kwargs=env_options,
            observer_options=observer_options,
            controller_options=controller_options,
            cli_args=cli_args,
            randomize=randomize,
        )
    return RecordResult(Path(out_dir), written["dataset_id"], written["episodes"], written)


def compare(
    env: str,
    observers: Entry | Sequence[Entry],
    controllers: Entry | Sequence[Entry],
    *,
    episodes: int | None = None,
    seed: int | None = None,
    seeds: Sequence[int] | None = None,
    out_dir: str | Path | None = None,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    steps: int | None = None,
    env_options: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
    progress: bool = False,
    cli_args: Mapping[str, Any] | None = None,
    video_dir: str | Path | None = None,
    video_episodes: Sequence[int] | None = None,
    rerun_dir: str | Path | None = None,
    rerun_episodes: Sequence[int] | None = None,
) -> ComparisonResult:
    """Every (observer, controller) pair on the same episodes (``seeds``, or ``episodes``
    from ``seed``: the module docstring), with intervals, paired
    differences from the oracle and NEES/NIS
    (:func:`observer_gym.train.experiments.compare.run_comparison`); locally in ``workers``
    processes or as Ray tasks (``backend="ray"``), with the same records. ``video_dir``:
    an MP4 of the episodes ``video_episodes`` (default ``[0]``) of every pair whose
    observer reads camera images; ``rerun_dir``: a ``.rrd`` recording of the episodes
    ``rerun_episodes`` (default ``[0]``) of every pair (docs/watch.md).

    Example:
        >>> import tempfile
        >>> import observer_gym
        >>> with tempfile.TemporaryDirectory() as out:
        ...     result = observer_gym.compare("BallTable-v0", ["oracle", "kf-measurements"],
        ...                                   "lqr", seeds=range(3), steps=150, out_dir=out)
        >>> [(pair.observer, pair.controller) for pair in result.pairs]
        [('oracle', 'lqr'), ('kf-measurements', 'lqr')]
        >>> oracle_m, kf_m = (p.statistics["mean_distance_m"]["mean"] for p in result.pairs)
        >>> bool(abs(kf_m - oracle_m) < 1e-3)  # the filter costs under a millimetre here
        True
    """
    from observer_gym.train.experiments.compare import run_comparison
    from observer_gym.train.reports.compare_report import comparison_text

    listed = episode_seeds(episodes, seed, seeds)
    found = _names(_listed(observers), _listed(controllers), workers, backend)
    folder = _out_dir(out_dir, "compare")
    with entries.objects_in_use(found.objects):
        results = run_comparison(
            env_id=env,
            observers=found.observers,
            controllers=found.controllers,
            seeds=listed,
            out_dir=folder,
            workers=workers,
            backend=backend,
            address=address,
            steps=steps,
            env_kwargs=env_options,
            progress=progress,
            cli_args=cli_args,
            observer_options=observer_options,
            controller_options=controller_options,
            video_dir=video_dir,
            video_episodes=video_episodes,
            rerun_dir=rerun_dir,
            rerun_episodes=rerun_episodes,
        )
    pairs = [
        PairResult(
            p["observer"],
            p["controller"],
            p["summary"],
            p["statistics"],
            p["consistency"],
            p["episodes"],
            p["vs_oracle"],
        )
        for p in results["pairs"]
    ]
    return ComparisonResult(
        Path(results["config"]["out_dir"]),
        pairs,
        results["files"],
        comparison_text(results),
        results,
    )


def sweep(
    env: str,
    vary: Mapping[str, Sequence[Any]] | Sequence[tuple[str, Sequence[Any]]],
    observers: Entry | Sequence[Entry],
    controllers: Entry | Sequence[Entry],
    *,
    out_dir: str | Path,
    episodes: int | None = None,
    seed: int | None = None,
    seeds: Sequence[int] | None = None,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    steps: int | None = None,
    env_options: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
    second_metric: str | None = None,
    progress: bool = False,
    cli_args: Mapping[str, Any] | None = None,
    on_cell: Callable[[str], None] | None = None,
    video_dir: str | Path | None = None,
    video_episodes: Sequence[int] | None = None,
    rerun_dir: str | Path | None = None,
    rerun_episodes: Sequence[int] | None = None,
) -> SweepOutcome:
    """Every cell (grid point of ``vary`` x observer x controller) on the same seeds,
    resumable from ``out_dir`` (:func:`observer_gym.train.experiments.sweep.run_sweep`);
    ``episodes`` from ``seed``, or ``seeds`` (consecutive): the module docstring.
    ``progress`` draws a bar over the episodes; ``on_cell`` is called with one line for
    each cell as it finishes (the command prints it on stderr when no bar can be drawn).
    ``video_dir``: an MP4 of the episodes ``video_episodes`` (default ``[0]``) of every
    cell run now whose observer reads camera images; ``rerun_dir``: a ``.rrd`` recording
    of the episodes ``rerun_episodes`` (default ``[0]``) of every cell run now
    (docs/watch.md).

    Example:
        >>> import tempfile
        >>> import observer_gym
        >>> with tempfile.TemporaryDirectory() as out:
        ...     outcome = observer_gym.sweep("BallTable-v0", {"latency_s": [0.0, 0.05]},
        ...                                  "kf-measurements", "lqr", episodes=2, steps=100,
        ...                                  out_dir=out)
        >>> [cell["point"] for cell in outcome.cells]
        [{'latency_s': 0.0}, {'latency_s': 0.05}]
        >>> outcome.cells_run, outcome.cells_reused
        (2, 0)
    """
    from observer_gym.train.experiments.sweep import run_sweep
    from observer_gym.train.reports.sweep_report import sweep_text

    listed = episode_seeds(episodes, seed, seeds, consecutive=True)
    found = _names(_listed(observers), _listed(controllers), workers, backend)
    with entries.objects_in_use(found.objects):
        result = run_sweep(
            env_id=env,
            vary=vary,
            observers=found.observers,
            controllers=found.controllers,
            out_dir=out_dir,
            episodes=len(listed),
            seed=listed[0],
            workers=workers,
            backend=backend,
            address=address,
            steps=steps,
            env_kwargs=env_options,
            second_metric=second_metric,
            progress=progress,
            cli_args=cli_args,
            observer_options=observer_options,
            controller_options=controller_options,
            on_cell=on_cell,
            video_dir=video_dir,
            video_episodes=video_episodes,
            rerun_dir=rerun_dir,
            rerun_episodes=rerun_episodes,
        )
    text = sweep_text(
        result.results, result.out_dir, result.cells_run, result.cells_reused, result.wall_time_s
    )
    return SweepOutcome(
        result.out_dir,
        result.results["cells"],
        result.cells_run,
        result.cells_reused,
        result.files,
        text,
        result.results,
    )


def evaluate(
    model: str | Path,
    *,
    episodes: int | None = None,
    seed: int | None = None,
    seeds: Sequence[int] | None = None,
    observer: Entry | None = None,
    out_dir: str | Path | None = None,
    steps: int | None = None,
    workers: int = 1,
    progress: bool = False,
    cli_args: Mapping[str, Any] | None = None,
    video_dir: str | Path | None = None,
    video_episodes: Sequence[int] | None = None,
    rerun_file: str | Path | None = None,
    rerun_episode: int | None = None,
) -> RunResult:
    """Episodes of the agent trained in the folder ``model`` (one seed's run; or a shipped
    agent by name, ``"ppo:ball_table-estimate"`` or ``"ball_table-estimate"``) on its env
    with its training options, reading what it was trained on or ``observer``
    (:func:`observer_gym.train.experiments.evaluate.evaluate_agent`); ``video_dir``: MP4s
    of the episodes ``video_episodes`` and ``rerun_file``: a rerun recording of episode
    ``rerun_episode``, as :func:`run`'s.

    Example, a shipped agent (PPO on the kf's estimate of BallTable):
        >>> import tempfile
        >>> import observer_gym
        >>> with tempfile.TemporaryDirectory() as out:
        ...     result = observer_gym.evaluate("ppo:ball_table-estimate",
        ...                                    episodes=2, steps=150, out_dir=out)
        >>> result.summary["fraction_settled"]
        1.0
    """
    from observer_gym.train.experiments.evaluate import evaluate_agent
    from observer_gym.train.experiments.run import results_text
    from observer_gym.train.rl.run_dir import agent_folder

    listed = episode_seeds(episodes, seed, seeds, consecutive=True)
    run_dir = agent_folder(model)
    found = _names([] if observer is None else [observer], [], workers, "local")
    folder = _out_dir(out_dir, "evaluate")
    with entries.objects_in_use(found.objects):
        results = evaluate_agent(
            run_dir,
            len(listed),
            folder,
            seed=listed[0],
            observer=found.observers[0] if found.observers else None,
            steps=steps,
            workers=workers,
            progress=progress,
            cli_args=cli_args,
            video_dir=video_dir,
            video_episodes=video_episodes,
            rerun_file=rerun_file,
            rerun_episode=rerun_episode,
        )
    return _run_result(results, results_text(results, "evaluate"))
