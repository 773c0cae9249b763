"""The error contract under fuzzing: every reader refuses damaged input with CaraFileError.

A few hundred seeded mutations per reader (CI size; ``benchmarks/fuzz.py`` runs
thousands), each in a worker process with a time limit, so a hang or a crash fails the
test instead of the run.
"""

from __future__ import annotations

import collections
from collections.abc import Iterator

import pytest

from tests.conftest import shared_fixtures_dir

from .harness import READERS, Worker, run_fuzz

#: Inputs per reader here; the slow readers (videos decoded) get fewer.
N_CASES = {"take_import": 80, "video": 120}
DEFAULT_CASES = 200


@pytest.fixture(scope="module")
def worker() -> Iterator[Worker]:
    """One worker process for the module (restarted by the harness after a hang/crash)."""
    w = Worker(timeout=10.0, mem_limit_mb=3072)
    yield w
    w.stop()


@pytest.mark.parametrize("reader", sorted(READERS))
def test_reader_keeps_the_error_contract(reader: str, worker: Worker) -> None:
    fixtures = shared_fixtures_dir()
    outs = run_fuzz([reader], N_CASES.get(reader, DEFAULT_CASES), seed=0,
                    fixtures=fixtures if fixtures.is_dir() else None, worker=worker)
    count = collections.Counter(o.status for o in outs)
    bad = [f"case {o.case}: {o.status} {o.exc_type} at {o.where}: {o.message[:120]} "
           f"({o.mutation})" for o in outs if o.status in ("undocumented", "hang", "crash")]
    assert not bad, "\n".join(bad[:20])
    # the mutations reach both sides of the readers: some inputs still load
    assert count["documented"] > 0
    assert count["documented"] + count["ok"] == len(outs)
    assert max(o.rss_mb for o in outs) < 1024
