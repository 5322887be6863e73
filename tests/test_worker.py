"""The harness's child process: results, events, failures, time limits and budgets."""

from __future__ import annotations

import os
import signal
import time

from cocd.bench.worker import Worker


def _count(emit, n, pause=0.0):
    for k in range(n):
        emit({"k": k})
        time.sleep(pause)
    return {"pid": os.getpid(), "n": n}


def _fail(emit):
    emit("before")
    raise ValueError("no such   thing\nhere")


def _die(emit):
    emit("before")
    time.sleep(0.5)  # the event reaches the pipe before the child dies
    os.kill(os.getpid(), signal.SIGKILL)


def _exit(emit):
    os._exit(3)


def _allocate(emit, gib):
    return len(bytearray(int(gib * 2**30)))


def test_results_and_events_and_the_child_is_kept():
    seen = []
    with Worker() as worker:
        first = worker.run(_count, 3, on_event=seen.append)
        second = worker.run(_count, 1)
    assert first.status == "done" and first.result["n"] == 3
    assert first.events == [{"k": 0}, {"k": 1}, {"k": 2}] and seen == first.events
    assert second.result["pid"] == first.result["pid"]  # imports stay loaded
    assert first.elapsed > 0 and first.note == ""


def test_an_exception_is_an_outcome_on_one_line():
    with Worker() as worker:
        out = worker.run(_fail)
        after = worker.run(_count, 1)
    assert out.status == "error" and out.events == ["before"]
    assert out.note == "ValueError: no such thing here"
    assert after.status == "done"


def test_a_dead_child_is_an_outcome_and_the_next_job_gets_a_new_one():
    with Worker() as worker:
        killed = worker.run(_die)
        exited = worker.run(_exit)
        after = worker.run(_count, 1)
    assert killed.status == "error" and killed.note.startswith("killed by signal 9")
    assert killed.events == ["before"]
    assert exited.status == "error" and exited.note == "child exited with code 3"
    assert after.status == "done"


def test_limit_silence_and_budget_end_a_job():
    with Worker() as worker:
        warm = worker.run(_count, 1)
        limit = worker.run(_count, 100, 0.05, limit=1.0)
        # Events every 0.05 s: never silent for 1 s, so only the budget stops it.
        budget = worker.run(_count, 100, 0.05, silence=1.0, budget=1.5)
        silent = worker.run(_count, 3, 3.0, silence=1.0)
        after = worker.run(_count, 1)
    assert limit.status == "time_limit" and limit.note.startswith("killed after")
    assert 0 < len(limit.events) < 100 and limit.elapsed >= 1.0
    assert budget.status == "budget" and 10 < len(budget.events) < 100
    assert silent.status == "time_limit" and silent.silent >= 1.0 and len(silent.events) == 1
    # Every job that had to be killed left the next one a fresh child.
    assert after.status == "done" and after.result["pid"] != warm.result["pid"]


def test_memory_cap():
    # The child's imports (numba, scipy) reserve well under 4 GiB of address space.
    with Worker(memory_gb=4.0) as worker:
        out = worker.run(_allocate, 8.0)
        fits = worker.run(_allocate, 0.01)
    assert out.status == "error" and out.note == "out of memory (cap 4 GiB)"
    assert fits.status == "done" and fits.result == int(0.01 * 2**30)
