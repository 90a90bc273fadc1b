"""Where a training run's time goes: its wall time split by phase (:class:`PhaseTimes`), logged under tensorboard's
``time/`` and printed as one table at the end of the run (:func:`phase_table`).

The phases: ``environment`` (the vector environment's steps and resets, with its wrappers), ``belief`` (EM's belief
and its fusion over the links, in its vector environment wrapper), ``policy forward`` (the policy's forward passes
while collecting: actions, values), ``gradient epochs`` (what the algorithm does between one rollout's end and the
next one's start: SB3's ``train()``), ``E-step``, ``evaluation`` (``EvalCallback``), ``checkpoints``
(``CheckpointCallback``), ``callbacks`` (every other callback), ``logging`` (the logger's dumps: tensorboard, csv,
stdout) and ``other`` (the rest of SB3's loop: the rollout buffer, numpy and torch conversions). A phase's seconds are
its own: an E-step run inside a callback counts as the E-step, not the callback, so the phases sum to the wall time.
The floor of a run is its gradient epochs plus its policy's forward passes: what the networks themselves need.

Written here because SB3 logs only ``time/fps``; the timing wraps the run's objects (its environment, policy, logger,
E-step) for the run's length and restores them at its end, so that nothing it adds is saved with the model.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from functools import wraps
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback, EvalCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

#: The phases in the order the table prints them.
PHASES = ("environment", "belief", "policy forward", "gradient epochs", "E-step", "evaluation", "checkpoints",
          "callbacks", "logging", "other")
#: The phases whose sum is a run's floor: what its networks need.
FLOOR = ("policy forward", "gradient epochs")


class PhaseClock:
    """Seconds per phase, each phase's own (time spent in a phase entered inside another counts for the inner one),
    from :meth:`start` to :meth:`stop`; time outside every named phase counts as ``"other"``.

    :param clock: the clock (seconds), ``time.perf_counter`` unless a test gives its own
    """

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self._clock = clock
        self.seconds: dict[str, float] = dict.fromkeys(PHASES, 0.0)
        self._stack: list[str] = []
        self._since = self._started = 0.0
        self.wall = 0.0

    @property
    def running(self) -> bool:
        return bool(self._stack)

    @property
    def current(self) -> str | None:
        """The innermost phase running (None before :meth:`start` and after :meth:`stop`)."""
        return self._stack[-1] if self._stack else None

    def _switch(self) -> None:
        now = self._clock()
        self.seconds[self._stack[-1]] += now - self._since
        self._since = now

    def start(self) -> None:
        """Start the clock (in ``"other"``)."""
        if self.running:
            raise RuntimeError("the phase clock is already running")
        self._started = self._since = self._clock()
        self._stack = ["other"]

    def stop(self) -> float:
        """Stop the clock, closing every phase still open; the wall time since :meth:`start`."""
        if not self.running:
            raise RuntimeError("the phase clock is not running")
        self._switch()
        self._stack = []
        self.wall += self._since - self._started
        return self.wall

    def enter(self, name: str) -> None:
        """Enter phase ``name`` (one of :data:`PHASES`) inside the current one."""
        if name not in self.seconds:
            raise ValueError(f"phase must be one of {list(PHASES)}, got {name!r}")
        if self.running:
            self._switch()
            self._stack.append(name)

    def leave(self, name: str) -> None:
        """Leave phase ``name``, the innermost one."""
        if not self.running:
            return
        if self._stack[-1] != name or len(self._stack) == 1:
            raise RuntimeError(f"leaving phase {name!r} while {self._stack[-1]!r} is the innermost")
        self._switch()
        self._stack.pop()

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        """``with clock.phase(name):`` the block's time counts for ``name`` (but for phases entered inside it)."""
        self.enter(name)
        try:
            yield
        finally:
            self.leave(name)

    def timed(self, function: Callable[..., Any], name: str, unless: tuple[str, ...] = ()) -> Callable[..., Any]:
        """``function`` whose calls count for phase ``name``, but for calls made inside a phase of ``unless`` (which
        count for that phase: the policy's forward passes inside the gradient epochs)."""

        @wraps(function)
        def timed_call(*args: Any, **kwargs: Any) -> Any:
            if self.current in unless:
                return function(*args, **kwargs)
            with self.phase(name):
                return function(*args, **kwargs)

        return timed_call

    @property
    def floor(self) -> float:
        """The seconds of the :data:`FLOOR` phases."""
        return sum(self.seconds[name] for name in FLOOR)


def phase_table(seconds: dict[str, float], wall: float, title: str = "where the run's time went") -> str:
    """One table: each phase's seconds and share of the wall time, their sum, the floor (:data:`FLOOR`) and the wall
    time over it.

    :param seconds: seconds per phase (:attr:`PhaseClock.seconds`)
    :param wall: the run's wall time
    :param title: the table's first line
    """
    lines = [title, f"  {'phase':<18}{'seconds':>10}{'share':>8}"]
    for name in PHASES:
        if seconds.get(name, 0.0) > 0.0 or name in FLOOR:
            share = seconds.get(name, 0.0) / wall if wall > 0 else 0.0
            lines.append(f"  {name:<18}{seconds.get(name, 0.0):>10.2f}{share:>8.1%}")
    total = sum(seconds.values())
    floor = sum(seconds.get(name, 0.0) for name in FLOOR)
    lines.append(f"  {'sum':<18}{total:>10.2f}{(total / wall if wall > 0 else 0.0):>8.1%}")
    lines.append(f"  wall {wall:.2f} s; floor ({' + '.join(FLOOR)}) {floor:.2f} s; wall / floor "
                 + (f"{wall / floor:.2f}" if floor > 0 else "undefined"))
    return "\n".join(lines)


#: The phases' names in :func:`median_phase_table`'s columns.
SHORT = {"environment": "env", "policy forward": "forward", "gradient epochs": "gradients", "evaluation": "eval",
         "checkpoints": "ckpt"}


def median_phase_table(phases: dict[str, list[dict[str, float]]], walls: dict[str, list[float]]) -> str:
    """One row per arm of a benchmark whose arms take turns: the median seconds of each phase over the arm's turns,
    and its median wall time over its median floor.

    :param phases: each arm's seconds per phase, one dict per turn
    :param walls: each arm's wall times, one per turn
    """
    shown = [phase for phase in PHASES if any(p.get(phase, 0.0) > 0 for runs in phases.values() for p in runs)]
    width = max([20, *(len(name) + 2 for name in phases)])
    lines = ["median seconds per turn by phase (the floor: " + " + ".join(FLOOR) + ")",
             f"{'arm':<{width}}" + "".join(f"{SHORT.get(phase, phase):>11}" for phase in shown) + f"{'wall/floor':>12}"]
    for name, runs in phases.items():
        floor = statistics.median(sum(p.get(f, 0.0) for f in FLOOR) for p in runs)
        ratio = statistics.median(walls[name]) / floor if floor > 0 else float("nan")
        lines.append(f"{name:<{width}}" + "".join(f"{statistics.median(p.get(phase, 0.0) for p in runs):>11.2f}"
                                                  for phase in shown) + f"{ratio:>12.2f}")
    return "\n".join(lines)


def machine_load() -> dict[str, float]:
    """The machine's load now, to keep beside a run's time (a slow run on a busy machine says why): the load average
    over the last minute and the last five (runnable processes; this machine's cores beside them)."""
    one, five, _ = os.getloadavg()
    return {"load_1min": one, "load_5min": five, "cores": float(os.cpu_count() or 1)}


def load_title(start: dict[str, float], end: dict[str, float]) -> str:
    """A phase table's title for a run between two :func:`machine_load` readings."""
    return (f"where its training's time went (load average {start['load_1min']:.1f} at its start, "
            f"{end['load_1min']:.1f} at its end, {end['cores']:.0f} cores)")


def _callback_phase(callback: BaseCallback) -> str:
    if isinstance(callback, EvalCallback):
        return "evaluation"
    if isinstance(callback, CheckpointCallback):
        return "checkpoints"
    return "callbacks"


class PhaseTimes(CallbackList):
    """A callback that times a run by phase (see the module) around the callbacks it is given: pass it as
    ``model.learn(n, callback=PhaseTimes([...]))``. During training it logs each phase's seconds so far under
    ``time/`` (``time/gradient_epochs``, ...; at each rollout's end, for the next dump) and at the end it prints
    :func:`phase_table` (``verbose`` >= 1) and keeps the figures (:attr:`seconds`, :attr:`wall`, :meth:`table`).

    :param callbacks: the run's other callbacks, each timed as ``evaluation`` (an ``EvalCallback``), ``checkpoints``
        (a ``CheckpointCallback``) or ``callbacks``
    :param verbose: 1: print the table at the end of training
    :param clock: the clock (seconds), ``time.perf_counter`` unless a test gives its own
    """

    def __init__(self, callbacks: list[BaseCallback] | None = None, verbose: int = 0,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        super().__init__(list(callbacks or []))
        self.verbose = verbose
        self.clock = PhaseClock(clock)
        self._patched: list[tuple[Any, str, bool, Any]] = []

    @property
    def seconds(self) -> dict[str, float]:
        """Seconds per phase (:data:`PHASES`), summing to :attr:`wall`."""
        return dict(self.clock.seconds)

    @property
    def wall(self) -> float:
        """The training's wall time, from its start to its end."""
        return self.clock.wall

    def table(self) -> str:
        """:func:`phase_table` of the run."""
        return phase_table(self.seconds, self.wall)

    def _patch(self, owner: Any, attribute: str, name: str, unless: tuple[str, ...] = ()) -> None:
        """Time ``owner.attribute`` (a method) as phase ``name`` until the training ends."""
        had = attribute in vars(owner)
        self._patched.append((owner, attribute, had, vars(owner).get(attribute)))
        setattr(owner, attribute, self.clock.timed(getattr(owner, attribute), name, unless))

    def _unpatch(self) -> None:
        for owner, attribute, had, value in reversed(self._patched):
            if had:
                setattr(owner, attribute, value)
            else:
                delattr(owner, attribute)
        self._patched = []

    def _patch_run(self) -> None:
        from sb3_emmarl.common.latent.belief import BeliefWrapper  # (the latent package imports the callbacks)

        venv: VecEnv | None = self.model.env
        while venv is not None:
            phase = "belief" if isinstance(venv, BeliefWrapper) else "environment"
            if "__getstate__" not in vars(type(venv)):  # (not one that checkpoints pickle, as VecNormalize: its time
                for method in ("reset", "step", "step_async", "step_wait"):  # counts where it is called from)
                    self._patch(venv, method, phase)
            venv = venv.venv if isinstance(venv, VecEnvWrapper) else None
        policy = self.model.policy
        for method in ("forward", "_predict", "predict_values"):
            if hasattr(policy, method):
                self._patch(policy, method, "policy forward", unless=("gradient epochs", "E-step", "evaluation"))
        self._patch(self.model.logger, "dump", "logging")
        e_steps = [getattr(owner, "e_step", None) for owner in (self.model, *self.callbacks)]
        for e_step in (e for e in e_steps if e is not None):
            for method in ("add", "step"):
                self._patch(e_step, method, "E-step")

    def _child(self, callback: BaseCallback) -> AbstractContextManager[None]:
        """A child callback's call, timed as its phase."""
        return self.clock.phase(_callback_phase(callback))

    def _on_training_start(self) -> None:
        self.clock.start()
        for callback in self.callbacks:
            with self._child(callback):
                callback.on_training_start(self.locals, self.globals)
        self._patch_run()

    def _on_rollout_start(self) -> None:
        if self.clock.current == "gradient epochs":
            self.clock.leave("gradient epochs")
        for callback in self.callbacks:
            with self._child(callback):
                callback.on_rollout_start()

    def _on_step(self) -> bool:
        continue_training = True
        for callback in self.callbacks:
            with self._child(callback):
                continue_training = callback.on_step() and continue_training
        return continue_training

    def _on_rollout_end(self) -> None:
        for callback in self.callbacks:
            with self._child(callback):
                callback.on_rollout_end()
        for name, seconds in self.clock.seconds.items():
            self.logger.record(f"time/{name.replace(' ', '_').replace('-', '_').lower()}", round(seconds, 3))
        self.clock.enter("gradient epochs")

    def _on_training_end(self) -> None:
        if not self.clock.running:  # (rl_zoo3 ends its first callback's training once more, after SB3 has)
            return
        if self.clock.current == "gradient epochs":
            self.clock.leave("gradient epochs")
        self._unpatch()
        for callback in self.callbacks:
            with self._child(callback):
                callback.on_training_end()
        self.clock.stop()
        if self.verbose >= 1:
            print(self.table())


class PhaseTotals:
    """The phases of several runs summed (a benchmark script's many runs): :meth:`add` each run's
    :class:`PhaseTimes` (or its recorded seconds and wall time), then :meth:`table` for one table of them all."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = dict.fromkeys(PHASES, 0.0)
        self.wall = 0.0
        self.runs = 0

    def add(self, run: dict[str, float] | PhaseTimes, wall: float | None = None) -> None:
        """Count one run: its :class:`PhaseTimes` after its training, or its seconds per phase and its wall time."""
        seconds = run.seconds if isinstance(run, PhaseTimes) else run
        wall = run.wall if isinstance(run, PhaseTimes) else wall
        if wall is None:
            raise ValueError("add(seconds, wall): the run's wall time is needed beside its seconds per phase")
        unknown = sorted(set(seconds) - set(PHASES))
        if unknown:
            raise ValueError(f"phases must be among {list(PHASES)}, got {unknown}")
        for name, value in seconds.items():
            self.seconds[name] += value
        self.wall += wall
        self.runs += 1

    def table(self, title: str | None = None) -> str:
        """:func:`phase_table` of the runs together."""
        return phase_table(self.seconds, self.wall, title or f"where the training time of {self.runs} runs went")
