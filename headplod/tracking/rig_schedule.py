"""The scheduler that spreads the rig's chunk updates over frames (:class:`SolveScheduler`).

No frame waits for a chunk's solve. The call that completes a chunk only
takes its frames and their velocities; the update is a job (the
estimator's generator, :meth:`~.rig_estimator.RigEstimator.update_steps`,
which stops before each Gauss-Newton pass), and each later call runs a
fixed number of passes of it (``passes_per_step``). The call that finishes
it applies the result (:meth:`~.rig_estimator.RigEstimator.apply`). The
work per call is a count of passes, never a time: the results are the same
whatever the machine's speed, and the same as solving each chunk at once
(``synchronous``). A job still under way when the next chunk completes is
finished first, so each update starts from the last one's result.

A copy of the scheduler (``copy``, ``pickle``) restarts the job under way
from its chunk (a generator cannot be copied): the same result, its passes
run again.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Generator, Protocol

from .rig_estimator import ChunkUpdate
from .rig_frames import _Frame, take_velocities
from .rig_refine_config import RigRefineConfig

__all__ = ["SolveScheduler", "Step"]


class Solver(Protocol):
    """What the scheduler runs (:class:`~.rig_estimator.RigEstimator`)."""

    updates: int

    def update_steps(self, chunk: list[_Frame]) -> Generator[None, None, ChunkUpdate]: ...

    def apply(self, update: ChunkUpdate, since: list[_Frame]) -> bool: ...


@dataclass(frozen=True)
class Step:
    """What one call of the scheduler did.

    ``changed``: an update finished in it and changed the rig in use;
    ``passes``: the Gauss-Newton passes it ran (each over all of a chunk's
    frames); ``under_way``: an update is still running after it (its chunk
    taken, its result not applied yet).
    """

    changed: bool = False
    passes: int = 0
    under_way: bool = False


@dataclass
class _Job:
    """An update under way: its chunk, the generator running it, and whether it has reached its first
    pass (the generator's first step runs no pass)."""

    chunk: list
    steps: object
    started: bool = False


class SolveScheduler:
    """Collects frames into chunks and runs each chunk's update over the calls after (module docstring).

    Parameters
    ----------
    solver : Solver
        Makes an update's job from a chunk and applies its result (the
        estimator).
    chunk_frames : int
        Frames per chunk.
    passes_per_step : int
        Gauss-Newton passes of the update under way run per :meth:`add`.
    max_gap_frames : float
        Velocities come from neighbours at most this many frame periods
        apart (:func:`~.rig_frames.take_velocities`).
    synchronous : bool
        Solve a chunk in the call that completes it.
    first_at_once : bool
        Solve the first update (the solver's ``updates`` 0) in the call that
        completes its chunk.
    """

    def __init__(self, solver: Solver, chunk_frames: int, passes_per_step: int, max_gap_frames: float,
                 synchronous: bool = False, first_at_once: bool = False):
        self.solver = solver
        self.chunk_frames = int(chunk_frames)
        self.passes_per_step = int(passes_per_step)
        self.max_gap_frames = max_gap_frames
        self.synchronous = synchronous
        self.first_at_once = first_at_once
        self._job: _Job | None = None
        self.reset()

    @classmethod
    def from_config(cls, solver: Solver, config: RigRefineConfig) -> "SolveScheduler":
        """The scheduler of a refinement's settings (``chunk_frames``, ``passes_per_frame``, ...)."""
        return cls(solver, config.chunk_frames, config.passes_per_frame, config.max_gap_frames,
                   config.synchronous, config.first_at_once)

    def reset(self) -> None:
        """Nothing collected, no update under way, the work counted from 0."""
        self.cancel()
        self.pending: list[_Frame] = []       # frames collected towards the next chunk
        self.recent: deque = deque(maxlen=3)  # last frames, for velocities across chunks
        # Work done (each pass evaluates every frame of its chunk): in all, and in the last call.
        self.passes = 0
        self.frame_terms = 0
        self.last_step = Step()

    # ------------------------------------------------------------ each frame
    def add(self, frame: _Frame | None) -> Step:
        """One frame's call: keep ``frame`` (None: a frame without one), run ``passes_per_step`` passes of
        the update under way, and when the frames make a chunk, start its update (finishing the one under
        way first; solving it now when ``synchronous``, or when it is the first and ``first_at_once``).

        The frame given is among those the update under way moves onto a new rig when it changes it.
        """
        if frame is not None:
            self.pending.append(frame)
        start = self.passes
        changed = self._run(self.passes_per_step)
        if len(self.pending) >= self.chunk_frames:
            # A job still under way is finished first: the next one starts from its result.
            changed = self._run(None) or changed
            self._start_job()
            if self.synchronous or (self.first_at_once and not self.solver.updates):
                changed = self._run(None) or changed
        return self._step(changed, start)

    def flush(self) -> Step:
        """Finish the update under way, then solve the frames waiting for a full chunk (two or more: the
        end of a recording)."""
        start = self.passes
        changed = self._run(None)
        if len(self.pending) >= 2:
            self._start_job()
            changed = self._run(None) or changed
        return self._step(changed, start)

    def _step(self, changed: bool, start: int) -> Step:
        self.last_step = Step(bool(changed), self.passes - start, self._job is not None)
        return self.last_step

    # ------------------------------------------------ what the frames became
    def cancel(self) -> None:
        """Forget the update under way (its chunk's frames unused); nothing of it was applied."""
        job, self._job = self._job, None
        if job is not None:
            job.steps.close()

    def restart(self) -> None:
        """Start the update under way over on its chunk (the solver's prior changed under it)."""
        if self._job is not None:
            chunk = self._job.chunk
            self.cancel()
            self._job = _Job(chunk, self.solver.update_steps(chunk))

    def drop(self, recent: bool = True) -> None:
        """Drop the update under way and the frames collected towards the next one; with ``recent``, the
        last frames kept for velocities across chunks too."""
        self.cancel()
        self.pending = []
        if recent:
            self.recent.clear()

    def forget_motion(self) -> None:
        """The times of the frames collected so far do not describe the head's motion: no velocity is taken
        from or across them. The update under way keeps its chunk's velocities (taken before)."""
        for f in self.pending:
            f.motion_known = False
        self.recent.clear()

    # ------------------------------------------------------------------ jobs
    def _start_job(self) -> None:
        """The pending frames become a chunk and its update a job (not run yet)."""
        chunk, self.pending = self.pending, []
        take_velocities(self.recent, chunk, self.max_gap_frames)
        self.recent.extend(chunk[-2:])
        self._job = _Job(chunk, self.solver.update_steps(chunk))

    def _run(self, passes: int | None) -> bool:
        """Run the job for up to ``passes`` more passes (None: to its end); True when it finished and
        changed the rig in use. An exception inside the job ends it (its chunk is lost) and propagates."""
        ran = 0
        while self._job is not None and (passes is None or ran < passes):
            job = self._job
            try:
                next(job.steps)
            except StopIteration as end:
                self._count(job)
                self._job = None
                return bool(self.solver.apply(end.value, self.pending))
            except BaseException:
                self._job = None
                raise
            # Every step after the first ran one pass (the first only reaches the first pass).
            ran += self._count(job)
        return False

    def _count(self, job: _Job) -> int:
        """Count the pass the job's last step ran (none for its first step); the passes counted."""
        if not job.started:
            job.started = True
            return 0
        self.passes += 1
        self.frame_terms += len(job.chunk)
        return 1

    def __getstate__(self):
        # A generator cannot be copied or pickled: a copy restarts the update
        # under way from its chunk (the same result; its passes run again).
        state = self.__dict__.copy()
        job = state.pop("_job", None)
        state["_job_chunk"] = None if job is None else job.chunk
        return state

    def __setstate__(self, state):
        chunk = state.pop("_job_chunk", None)
        self.__dict__.update(state)
        self._job = None if chunk is None else _Job(chunk, self.solver.update_steps(chunk))
