"""One child process for every study: a job under a wall-clock limit and a memory cap.

A job is a module-level function ``job(emit, *args)``: it runs in a spawned
child, sends events to the parent with ``emit(event)`` as it goes, and its
return value is the result. :meth:`Worker.run` waits for it and returns an
:class:`Outcome`; a job that raises, a child that dies, runs out of memory,
overruns its time or falls silent is an outcome saying so, never an exception
in the parent. The child stays alive between jobs (its imports and compiled
kernels stay loaded) unless a job had to be killed; the next job then starts a
new one.

Use as a context manager::

    with Worker(memory_gb=12) as worker:
        outcome = worker.run(job, problem_path, limit=60.0, on_event=print)
"""

from __future__ import annotations

import math
import multiprocessing as mp
import queue as queue_mod
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

__all__ = ["Outcome", "Worker"]

#: Outcome statuses: the job returned; it overran ``limit`` or ``silence``; it used up
#: ``budget``; it raised, or the child died.
DONE, TIME_LIMIT, BUDGET, ERROR = "done", "time_limit", "budget", "error"
#: Seconds a new child may take to start (spawn and imports) before its job's clocks start.
STARTUP_S = 300.0


@dataclass
class Outcome:
    """What became of one job."""

    status: str
    result: Any = None
    events: list[Any] = field(default_factory=list)
    note: str = ""
    elapsed: float = 0.0
    #: Seconds between the last message (or the start) and the end.
    silent: float = 0.0


def short(exc: BaseException, limit: int = 300) -> str:
    """An exception's message on one line, at most ``limit`` characters."""
    return " ".join(str(exc).split())[:limit]


def _serve(jobs: Any, answers: Any, memory_gb: float | None, started: Any = None) -> None:
    """Child process: run jobs until told to stop; ``started`` is set as each job is taken
    (at once, unlike a message, even if the job then holds the interpreter in native code)."""
    if memory_gb is not None and math.isfinite(memory_gb):
        cap = int(memory_gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))

    def emit(event: Any) -> None:
        answers.put(("event", event))

    while True:
        item = jobs.get()
        if item is None:
            return
        job, args = item
        if started is not None:
            started.set()
        answers.put(("start", None))
        try:
            answers.put(("done", job(emit, *args)))
        except MemoryError:
            cap_text = "" if memory_gb is None else f" (cap {memory_gb:g} GiB)"
            answers.put(("error", f"out of memory{cap_text}"))
        except Exception as exc:
            answers.put(("error", f"{type(exc).__name__}: {short(exc)}"))


class Worker:
    """A spawned child that runs jobs one at a time (see the module's docstring).

    Parameters
    ----------
    memory_gb : float, optional
        Address-space cap of the child (GiB); none by default.
    """

    def __init__(self, memory_gb: float | None = None) -> None:
        self.memory_gb = memory_gb
        self._ctx = mp.get_context("spawn")
        self._proc: Any = None
        self._jobs: Any = None
        self._answers: Any = None
        self._started = self._ctx.Event()

    def __enter__(self) -> Worker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the child (a new one starts with the next job)."""
        if self._proc is not None and self._proc.is_alive():
            self._jobs.put(None)
            self._proc.join(timeout=5)
        self._kill()

    def _kill(self) -> int | None:
        """Kill the child if it is alive; its exit code (None if it had to be killed)."""
        if self._proc is None:
            return None
        code: int | None = self._proc.exitcode
        if self._proc.is_alive():
            self._proc.kill()
        self._proc.join()
        self._proc = None
        return code

    def run(
        self,
        job: Callable[..., Any],
        *args: Any,
        limit: float | None = None,
        silence: float | None = None,
        budget: float | None = None,
        on_event: Callable[[Any], None] | None = None,
    ) -> Outcome:
        """Run ``job(emit, *args)`` in the child and wait for it.

        ``limit``: seconds for the whole job; ``silence``: the most seconds
        between two messages of the job (both end it as ``time_limit``; both count
        from when the child takes the job, so a new child's start-up is not counted);
        ``budget``: seconds after which the job is stopped as ``budget``, its
        events kept. ``on_event`` receives each event as it arrives.
        """
        if self._proc is None or not self._proc.is_alive():
            self._jobs, self._answers = self._ctx.Queue(), self._ctx.Queue()
            self._proc = self._ctx.Process(
                target=_serve,
                args=(self._jobs, self._answers, self.memory_gb, self._started),
                daemon=True,
            )
            self._proc.start()
        self._started.clear()
        self._jobs.put((job, args))
        out = Outcome(status=ERROR)
        start = last = time.perf_counter()
        started = False  # the job's clocks start when the child takes it
        limit = math.inf if limit is None else limit
        silence = math.inf if silence is None else silence
        budget = math.inf if budget is None else budget
        try:
            while True:
                now = time.perf_counter()
                if not started and self._started.is_set():
                    start = last = now
                    started = True
                if started:
                    wait = min(
                        1.0, limit - (now - start), silence - (now - last), budget - (now - start)
                    )
                else:
                    wait = min(0.05, STARTUP_S - (now - start))
                try:
                    kind, body = self._answers.get(timeout=max(0.01, wait))
                except queue_mod.Empty:
                    now = time.perf_counter()
                    out.elapsed, out.silent = now - start, now - last
                    if not self._proc.is_alive():
                        self._died(out)
                        return out
                    if not started:
                        if out.elapsed <= STARTUP_S:
                            continue
                        out.note = f"the child did not start in {STARTUP_S:g} s"
                    elif out.elapsed > budget:
                        out.status, out.note = BUDGET, f"stopped after {out.elapsed:.0f} s"
                    elif out.elapsed > limit or out.silent > silence:
                        out.status, out.note = TIME_LIMIT, f"killed after {out.elapsed:.0f} s"
                    else:
                        continue
                    self._kill()
                    return out
                if kind == "start":
                    if not started:
                        start = last = time.perf_counter()
                        started = True
                    continue
                last = time.perf_counter()
                if kind == "event":
                    out.events.append(body)
                    if on_event is not None:
                        on_event(body)
                    continue
                out.elapsed = last - start
                if kind == "done":
                    out.status, out.result = DONE, body
                else:
                    out.status, out.note = ERROR, str(body)
                return out
        except BaseException:
            self._kill()  # interrupted in the parent: no child is left behind
            raise

    def _died(self, out: Outcome) -> None:
        """The child died: what it said before dying, else how it died."""
        while True:  # it may have left messages in the pipe
            try:
                kind, body = self._answers.get(timeout=0.2)
            except queue_mod.Empty:
                break
            if kind == "event":
                out.events.append(body)
            elif kind == "start":
                continue
            elif kind == "done":
                out.status, out.result = DONE, body
            else:
                out.status, out.note = ERROR, str(body)
        code = self._kill()
        if out.status == DONE or out.note:
            return
        out.status = ERROR
        if code is not None and code < 0:
            out.note = f"killed by signal {-code} ({out.elapsed:.0f} s)"
        else:
            out.note = f"child exited with code {code}"
