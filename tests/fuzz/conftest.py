"""The fuzz suite's Hypothesis profiles and its tally.

Profiles (chosen by the environment variable HYPOTHESIS_PROFILE, default "ci"):

- "ci": few examples per property, derandomized (the same examples on every run, so CI is
  reproducible) and no example database; the whole suite runs in well under a minute.
- "slow": many more examples, random each run; ``HYPOTHESIS_PROFILE=slow pytest
  tests/fuzz``. No database either (nothing written to the work tree): a failure prints
  its ``@reproduce_failure`` blob.
- "long": as many examples as "slow", derandomized: CI's longer fuzzing step
  (``.ci/run``), reproducible like "ci".
- "dev": the ci examples without shrinking (a failure is reported at once, unshrunk).

Every test here carries the ``fuzz`` marker (added at collection, below): the default run
(``-m 'not slow and not fuzz'``) leaves them to CI's fuzzing step, which runs them with the
"long" profile; ``pytest -m fuzz tests/fuzz`` runs them with the "ci" profile.

At the end of the run the table of what was tried per category (accepted, or rejected
with a ValueError) is printed, summed over the xdist workers.
"""

from __future__ import annotations

import json
import os
from collections import Counter

import pytest
from fuzzlib import COUNTS
from hypothesis import HealthCheck, Phase, settings

_COMMON = {
    "deadline": None,
    "suppress_health_check": [HealthCheck.too_slow, HealthCheck.data_too_large],
    "print_blob": True,
}
settings.register_profile("ci", max_examples=40, derandomize=True, database=None, **_COMMON)
settings.register_profile("slow", max_examples=400, database=None, **_COMMON)
settings.register_profile("long", max_examples=400, derandomize=True, database=None, **_COMMON)
# While fixing: the ci examples, failures reported unshrunk (fast).
settings.register_profile(
    "dev", parent=settings.get_profile("ci"), phases=[Phase.explicit, Phase.generate]
)
PROFILE = os.environ.get("HYPOTHESIS_PROFILE", "ci")
settings.load_profile(PROFILE)

_GATHERED: Counter[tuple[str, str]] = Counter()
_HERE = os.path.dirname(__file__)


@pytest.hookimpl(tryfirst=True)  # before ``-m`` deselects by marker
def pytest_collection_modifyitems(items):
    for item in items:
        if str(item.path).startswith(_HERE + os.sep):
            item.add_marker(pytest.mark.fuzz)


def pytest_sessionfinish(session):
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:  # an xdist worker: hand the tally to the controller
        workeroutput["fuzz_counts"] = json.dumps([[c, o, n] for (c, o), n in COUNTS.items()])


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    for category, outcome, n in json.loads(node.workeroutput.get("fuzz_counts", "[]")):
        _GATHERED[(category, outcome)] += n


def pytest_terminal_summary(terminalreporter):
    counts = _GATHERED + COUNTS  # workers' (xdist) or this process's
    if not counts:
        return
    categories = sorted({c for c, _ in counts})
    rows = [
        (c, counts[(c, "accepted")] + counts[(c, "rejected")], counts[(c, "accepted")])
        for c in categories
    ]
    rows = [(c, tried, acc, tried - acc) for c, tried, acc in rows]
    total = tuple(sum(r[i] for r in rows) for i in (1, 2, 3))
    width = max(len("category"), *(len(c) for c in categories))
    write = terminalreporter.write_line
    terminalreporter.section(f"fuzz tally (hypothesis profile {PROFILE!r})")
    header = (
        f"{'category':<{width}} | {'tried':>6} | {'accepted':>8} | {'rejected (ValueError)':>21}"
    )
    write(header)
    write("-" * len(header))
    for c, tried, acc, rej in rows:
        write(f"{c:<{width}} | {tried:>6} | {acc:>8} | {rej:>21}")
    write("-" * len(header))
    write(f"{'total':<{width}} | {total[0]:>6} | {total[1]:>8} | {total[2]:>21}")
