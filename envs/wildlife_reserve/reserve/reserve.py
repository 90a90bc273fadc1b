"""
# Wildlife Reserve

| Import             | `from wildlife_reserve import reserve_v1`                  |
|--------------------|------------------------------------------------------------|
| Actions            | Discrete (default) or continuous                           |
| Parallel API       | Yes                                                        |
| Manual control     | No                                                         |
| Agents             | `agents= ['uav_0', 'uav_1', ..., 'uav_9']` (default)       |
| Agents             | `n_uavs` (default 10, 1 to 1000; see the bounds in env.md) |
| Action shape       | `Discrete(15)` or `Box(-1, 1, (3,))`                       |
| Observation shape  | `(7 * (2r + 1)^2 + 6 + 3 * max_neighbors + 3 * belief_size^2,)`; 553 by default |
| With `compass`     | 4 more floats (offsets to the nearest den and road entry)  |
| With `agent_ids`   | `n_uavs` more floats (a one-hot of the UAV's index)        |
| Observation values | [-1, 1]                                                    |
| State shape        | `(4 n_uavs + 4 n_poachers + 3 n_leopards + 2 belief_size^2 + 1,)` |

A team of UAVs patrols a wildlife reserve against poachers who hunt its leopards. Each
episode has a hidden scenario mode `z*` (poacher strategy x weather) that decides where and
when poachers enter, how they move, where their signs (tracks, snares, camps, vehicles) lie and
how well the sensors see; the UAVs never observe it (it is in `infos[agent]["mode"]` for
evaluation only). The full card, with every argument and its range, is `docs/env.md`.

### Observations
Per UAV, a flat float32 vector: an egocentric `(2r + 1) x (2r + 1)` window of seven channels
(visual occlusion, risk, time since the team last saw the cell as far as this UAV knows,
poacher signals, leopard signals, other UAVs, signs of poacher activity), then own position,
velocity, battery, episode progress, the relative positions of up to `max_neighbors` UAVs within
`R_c` (padded, with a presence flag), and three `belief_size x belief_size` maps built from what
this UAV knows (its own history and what was shared with it): time since each block was flown
over, poacher activity, and the signs of poacher activity found there; with `compass=True`, the
offsets from the UAV to the nearest den and the nearest road entry; with `agent_ids=True`, a
one-hot of the UAV's index last.
`env.split_observation(obs)` names the parts.

### Actions
Discrete: `move + 5 * comm`, with move in {stay, up, down, left, right} and comm in {none,
broadcast, query the nearest neighbour}. Continuous: `(d_row, d_col, comm)` in [-1, 1]; the
first two scale `uav_speed`, comm > 1/3 broadcasts and comm < -1/3 queries.

### Rewards
One shared team reward per step: `detection` per poacher detected, `coverage` per high-risk
cell seen for the first time, `sign` per sign of poacher activity the team finds for the first
time, minus `poaching` per poaching event, `collision` per pair of UAVs in one cell and `energy`
per unit of battery spent. `shaping > 0` mixes in each UAV's own share. With `coverage_sectors=True` (a diagnostic),
`coverage` pays only for the high-risk cells in the sector of the episode's poacher strategy.

### Infos
`infos[agent]["mode"]` (the hidden mode, for evaluation), `infos[agent]["heard_from"]` (the
indices of the teammates whose messages reached this UAV this step) and, on the last step,
`infos[agent]["metrics"]`.

### Version History
* v1: the current version (`reserve_v1`, zoo id `WildlifeReserve-v1`): the name it took when the rule that the version
  rises whenever an episode can change was applied; what each sb3-emmarl release changed in it is in CHANGELOG.md
* v0: the name it kept from its first release while its observation and dynamics changed many times; `reserve_v0` and
  `WildlifeReserve-v0` still give v1, with a warning
"""

from __future__ import annotations

import functools
import threading
from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

from wildlife_reserve.reserve import kernels
from wildlife_reserve.reserve.compilation import announce_compilation
from wildlife_reserve.reserve.config import ReserveConfig
from wildlife_reserve.reserve.kernels.constants import COMM_BROADCAST, COMM_NONE, COMM_QUERY, N_COMMS, N_MOVES
from wildlife_reserve.reserve.modes import N_MODES
from wildlife_reserve.reserve.observation import global_state
from wildlife_reserve.reserve.world import ReserveWorld
from wildlife_reserve.utils.checks import check_action_dict, check_agent, check_int, check_options, check_seed, discrete_action

if TYPE_CHECKING:
    from wildlife_reserve.reserve.rendering import ReserveRenderer

#: The keys ``reset(options=...)`` takes.
RESET_OPTIONS = ("mode", "uav_positions")
_NO_CHOICES = np.zeros(0, dtype=np.int64)  # continuous actions: decoded before the step's compiled call


def env(**kwargs: Any) -> wrappers.OrderEnforcingWrapper:
    """The AEC form of the reserve, with PettingZoo's standard wrappers.

    :param kwargs: see :class:`~wildlife_reserve.reserve.config.ReserveConfig`
    """
    aec = raw_env(**kwargs)
    if not aec.unwrapped.config.continuous_actions:
        aec = _InBoundsOrStay(aec)
    return wrappers.OrderEnforcingWrapper(aec)


class _InBoundsOrStay(wrappers.AssertOutOfBoundsWrapper):
    """PettingZoo's check that a discrete action is in its space, taking ``None`` as "stay, no message" (as the
    parallel form does) rather than refusing it."""

    def step(self, action: Any) -> None:
        if action is None:
            wrappers.BaseWrapper.step(self, action)
        else:
            super().step(action)


def raw_env(**kwargs: Any) -> parallel_to_aec_wrapper:
    """The AEC form of the reserve without wrappers.

    :param kwargs: see :class:`~wildlife_reserve.reserve.config.ReserveConfig`
    """
    return parallel_to_aec_wrapper(parallel_env(**kwargs))


def parallel_env(**kwargs: Any) -> ReserveParallelEnv:
    """The parallel form of the reserve (what SuperSuit and the training code use).

    :param kwargs: see :class:`~wildlife_reserve.reserve.config.ReserveConfig`
    """
    return ReserveParallelEnv(**kwargs)


#: The arguments :func:`compile_kernels` has played an episode with in this process, and its lock.
_COMPILED: set[str] = set()
_COMPILING = threading.Lock()
#: The steps :func:`compile_kernels` plays at most.
COMPILE_STEPS = 1000


def compile_kernels(**kwargs: Any) -> None:
    """Compile the reserve's numba kernels for these arguments in this process (once per process and arguments).

    numba compiles a kernel at its first call with each set of argument types and caches the machine code beside
    the ``kernels`` modules: a process started after the cache is written loads it in well under a second, while processes
    started before compile again, each for tens of seconds and over a hundred MiB of peak memory. Tools that time runs
    in fresh processes (the paper's experiments, ``zoo/compare.py``, the benchmarks) call this in the parent first, so
    that no run's time or peak memory counts the compilation. It plays one episode (at most :data:`COMPILE_STEPS`
    steps) with actions drawn from seeded action spaces; nothing else's random state is touched.

    :param kwargs: the reserve's arguments (see :class:`~wildlife_reserve.reserve.config.ReserveConfig`); invalid
        ones raise ``ValueError`` as the environment does
    """
    key = repr(sorted(kwargs.items()))
    with _COMPILING:
        if key in _COMPILED:
            return
        reserve = parallel_env(**kwargs)
        reserve.reset(seed=0)
        for i, agent in enumerate(reserve.possible_agents):
            reserve.action_space(agent).seed(i)
        for _ in range(COMPILE_STEPS):
            if not reserve.agents:
                break
            reserve.step({agent: reserve.action_space(agent).sample() for agent in reserve.agents})
        reserve.close()
        _COMPILED.add(key)


class ReserveParallelEnv(ReserveWorld, ParallelEnv):
    """UAV patrol of a wildlife reserve against poachers (PettingZoo ``ParallelEnv``).

    State lives in numpy arrays over agents and cells; grids are padded by the sensor radius so
    that every observation window is one fancy-index away. Internal arrays are public for tests
    and tools: ``uav_pos`` (float rows/cols), ``battery``, ``grounded``, ``poacher_pos``,
    ``poacher_status``, ``leopard_pos``, ``leopard_alive``, ``terrain``, ``risk``, ``signs``
    (:class:`~wildlife_reserve.reserve.signs.Signs`) and ``team``
    (:class:`~wildlife_reserve.reserve.knowledge.TeamKnowledge`: what each UAV knows, the links), ``sensors``
    (:class:`~wildlife_reserve.reserve.sensing.SensorTables` of the episode's weather).

    :param kwargs: see :class:`~wildlife_reserve.reserve.config.ReserveConfig`
    """

    metadata: dict[str, Any] = {"name": "wildlife_reserve_v1", "render_modes": ["human", "rgb_array"],
                                "is_parallelizable": True, "render_fps": 10}

    def __init__(self, **kwargs: Any) -> None:
        cfg = ReserveConfig.from_kwargs(**kwargs)  # validates everything before anything is allocated
        super().__init__(cfg)
        self.render_mode = cfg.render_mode
        self.possible_agents = [f"uav_{i}" for i in range(self.n)]
        self.agents = self.possible_agents[:]
        self.np_random: np.random.Generator | None = None
        self._renderer: ReserveRenderer | None = None
        self._ready = False  # an episode to step: set by reset()

    # ------------------------------------------------------------------ spaces
    @functools.cache  # noqa: B019 (one space object per agent, as PettingZoo requires)
    def observation_space(self, agent: str) -> spaces.Box:
        check_agent(agent, self.possible_agents)
        return spaces.Box(low=-1.0, high=1.0, shape=(self.obs_dim,), dtype=np.float32)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Space:
        check_agent(agent, self.possible_agents)
        if self.config.continuous_actions:
            return spaces.Box(low=-1.0, high=1.0, shape=(3,), dtype=np.float32)
        return spaces.Discrete(N_MOVES * N_COMMS)

    @functools.cached_property
    def state_space(self) -> spaces.Box:
        return spaces.Box(low=-1.0, high=1.0, shape=(self.state_dim,), dtype=np.float32)

    # ------------------------------------------------------------------ reset
    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start an episode.

        :param seed: seeds every random draw of the episode (and of later unseeded resets)
        :param options: ``{"mode": int}`` fixes the hidden mode for this episode;
            ``{"uav_positions": array (n, 2)}`` sets the UAVs' start cells (row, col); a misspelling of these is
            refused, another key is named in a warning and ignored (:func:`~wildlife_reserve.utils.checks.check_options`).
        :raise ValueError: for a bad seed or option, before anything changes (the previous episode, if any, is left as
            it was)
        """
        seed, mode, start = self._check_reset(seed, options)
        announce_compilation()
        self._ready = False  # until this reset is through, step(), state() and the rest refuse
        obs = self.start_episode(*self._seed(seed), mode, start)
        self.agents = self.possible_agents[:]
        infos = {a: {"mode": self.mode, "heard_from": ()} for a in self.agents}
        self._ready = True
        if self.render_mode == "human":
            self.render()
        return {a: obs[i] for i, a in enumerate(self.agents)}, infos

    def _seed(self, seed: int | None) -> tuple[int, int, int, int]:
        """The episode's seeds: every generator of an episode comes from ``np_random``, seeded by ``seed`` when given.

        :return: the seeds of the map and the UAVs' start cells, of the mode, of the ground actors and of the step
        """
        if seed is not None or self.np_random is None:
            self.np_random, _ = seeding.np_random(seed)
        world_seed, mode_seed, ground_seed, step_seed = self.np_random.integers(0, 2**32, size=4).tolist()
        return world_seed, mode_seed, ground_seed, step_seed

    def _check_reset(self, seed: Any, options: dict | None) -> tuple[int | None, int | None, np.ndarray | None]:
        """``reset``'s arguments checked before anything changes: the seed (an int >= 0, numpy's included, or None),
        the mode (``options["mode"]``, else the configuration's) and the UAVs' start cells (floored), or None."""
        seed = check_seed(seed)
        given = check_options(options, RESET_OPTIONS)
        mode = given.get("mode", self.config.mode)
        if mode is not None:
            mode = check_int("mode", mode, 0, N_MODES - 1)
        start = None
        if "uav_positions" in given:
            shape = (self.height, self.width)
            try:
                start = np.asarray(given["uav_positions"], dtype=np.float64)
            except (TypeError, ValueError):
                start = np.full(0, np.nan)
            if start.shape != (self.n, 2) or not np.isfinite(start).all() or (start < 0).any() or (start >= shape).any():
                raise ValueError(f"options['uav_positions'] must be {self.n} (row, col) cells inside {shape}, "
                                 f"got {given['uav_positions']!r}")
            start = np.floor(start)
        return seed, mode, start

    def _require_episode(self, method: str) -> None:
        """Refuse ``method`` before the first reset (or after a reset that failed)."""
        if not self._ready:
            raise RuntimeError(f"{method}() needs an episode: call reset() first")

    # ------------------------------------------------------------------ step
    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        """Advance every UAV, poacher and leopard one step.

        :param actions: one action per live agent
        """
        self._require_episode("step")
        if not self.agents:
            raise RuntimeError("step() called on a finished episode: call reset() first")
        agents = self.agents
        obs, rewards_arr, terminated, truncated, info, heard = self._advance(*self._decode_actions(actions))
        observations = dict(zip(agents, obs))
        rewards = dict(zip(agents, rewards_arr.tolist()))
        terminations = dict.fromkeys(agents, terminated)
        truncations = dict.fromkeys(agents, truncated)
        infos = {a: {**info, "heard_from": senders} for a, senders in zip(agents, heard)}
        return observations, rewards, terminations, truncations, infos

    def step_arrays(self, actions: np.ndarray, out: np.ndarray | None = None) -> tuple[
            np.ndarray, np.ndarray, bool, bool, dict[str, Any], list[tuple[int, ...]]]:
        """:meth:`step` on arrays, in agent order, without the per-agent dictionaries (the fast vector environment,
        ``sb3_emmarl.common.vec_env.ReserveVecEnv``, steps the reserve through it; ``step`` is this plus the dicts).

        :param actions: ``(n,)`` ints (discrete) or ``(n, 3)`` floats (continuous), one row per UAV
        :param out: a C-contiguous float32 ``(n, obs_dim)`` array to write the observations into (returned), or None
        :return: observations ``(n, obs_dim)``, rewards ``(n,)``, terminated, truncated (every UAV alike), the info
            every UAV shares (``mode``, and ``metrics`` on the last step) and each UAV's ``heard_from``
        """
        self._require_episode("step_arrays")
        if not self.agents:
            raise RuntimeError("step_arrays() called on a finished episode: call reset() first")
        if out is not None and (out.shape != (self.n, self.obs_dim) or out.dtype != np.float32
                                or not out.flags.c_contiguous):
            raise ValueError(f"out must be a C-contiguous float32 array of shape {(self.n, self.obs_dim)}, got "
                             f"{out.dtype} {out.shape}")
        return self._advance(*self._action_arrays(actions), out)

    def _advance(self, choices: np.ndarray, move: np.ndarray, comm: np.ndarray, out: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, bool, bool, dict[str, Any], list[tuple[int, ...]]]:
        """The step itself, from :meth:`_action_arrays`' actions (see :meth:`step_arrays` for what it returns): the
        world's :meth:`~wildlife_reserve.reserve.world.ReserveWorld.advance`, then what the agents receive."""
        obs = np.empty((self.n, self.obs_dim), dtype=np.float32) if out is None else out
        try:
            outcome = self.advance(choices, move, comm, obs)
        except kernels.ActionError:  # raised before anything changed
            raise self._bad_actions(choices) from None
        truncated = self.t >= self.max_cycles
        info: dict[str, Any] = {"mode": self.mode}
        if truncated or outcome.terminated:
            info["metrics"] = self.episode_metrics()
            self.agents = []
        if self.render_mode == "human":
            self.render()
        terminated = outcome.terminated
        return obs, outcome.rewards, terminated, truncated and not terminated, info, self.team.heard_from(outcome.masks)

    # ------------------------------------------------------------------ helpers
    def _decode_actions(self, actions: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_action_arrays` of the action dict (a missing or None action means "stay, no message"; a key that is
        no live agent is refused); each action is checked as :meth:`step_arrays` checks its rows, and a bad one is
        refused naming its agent."""
        check_action_dict(actions, self.agents)
        if self.config.continuous_actions:
            act = np.zeros((self.n, 3))
            for i, agent in enumerate(self.agents):
                value = actions.get(agent)
                if value is not None:
                    row = np.asarray(value)
                    if row.shape != (3,) or row.dtype.kind not in "iuf" or not np.all(np.isfinite(row)):
                        raise ValueError(f"the action of {agent} must be 3 finite floats (d_row, d_col, comm) or None, "
                                         f"got {value!r}")
                    act[i] = row
            return self._action_arrays(act)
        choices = np.zeros(self.n, dtype=np.int64)  # 0: stay, no message
        for i, agent in enumerate(self.agents):
            value = actions.get(agent)
            if value is not None:
                choices[i] = discrete_action(agent, value, N_MOVES * N_COMMS, none_too=True)
        return self._action_arrays(choices)

    def _action_arrays(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The step's actions from ``(n,)`` ints or ``(n, 3)`` floats, as ``kernels.advance_world`` takes them:
        ``(n,)`` int64 discrete choices that it decodes (and checks) into the ``(n, 2)`` unit moves and ``(n,)``
        communication choices that follow them, or no choices and the moves and choices decoded here."""
        if self.config.continuous_actions:
            act = np.asarray(actions, dtype=np.float64)
            if act.size != 3 * self.n:
                raise ValueError(f"continuous actions must be {self.n} rows of 3 floats, got shape {act.shape}")
            act = act.reshape(self.n, 3)
            if not np.all(np.isfinite(act)):
                raise ValueError(f"continuous actions must be finite, got {act}")
            act = np.clip(act, -1.0, 1.0)
            comm = np.select([act[:, 2] > 1 / 3, act[:, 2] < -1 / 3], [COMM_BROADCAST, COMM_QUERY], COMM_NONE)
            return _NO_CHOICES, np.ascontiguousarray(act[:, :2]), comm
        choices = np.asarray(actions).reshape(-1)
        if choices.dtype != np.int64 or choices.size != self.n:  # (SB3 and SuperSuit pass n int64s: checked compiled)
            whole = choices.dtype.kind in "iu" or (choices.dtype.kind == "f"
                                                   and np.array_equal(choices, np.floor(choices)))
            if not whole or choices.size != self.n or choices.min() < 0 or choices.max() >= N_MOVES * N_COMMS:
                raise self._bad_actions(choices)
            choices = choices.astype(np.int64)
        return choices, self._move, self._comm

    def _bad_actions(self, choices: np.ndarray) -> ValueError:
        return ValueError(f"discrete actions must be {self.n} ints in [0, {N_MOVES * N_COMMS - 1}], got {choices}")

    # ------------------------------------------------------------------ public extras
    def split_observation(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        """Split flat observations ``(..., obs_dim)`` into their named parts (see ``observation_layout``)."""
        obs = np.asarray(obs)
        layout = self.observation_layout
        return {name: obs[..., part].reshape(*obs.shape[:-1], *shape) for name, (part, shape) in layout.items()}

    def episode_metrics(self) -> dict[str, float]:
        """The episode's metrics so far (what ``infos[agent]["metrics"]`` holds at the end).

        ``coverage_efficiency`` is the share of high-risk cells seen; ``detection_rate`` the share of
        entered poachers detected (0 if none entered); ``time_to_first_detection`` counts steps from
        the first entry to the first true detection, and runs to the current step when none happened;
        ``signs_found`` counts the distinct signs of poacher activity the team found.
        """
        self._require_episode("episode_metrics")
        m = self.metrics
        entered = m["poachers_entered"]
        if self.first_entry_time is None:
            ttfd = 0
        else:
            ttfd = (self.first_detection_time if self.first_detection_time is not None else self.t) - self.first_entry_time
        return {
            "team_reward": float(m["team_reward"]),
            "coverage_efficiency": float(self._covered() / max(self.n_high_risk, 1)),
            "detection_rate": float(m["poachers_detected"] / entered) if entered else 0.0,
            "false_alarms": int(m["false_alarms"]),
            "poaching_events": int(m["poaching_events"]),
            "collisions": int(m["collisions"]),
            "energy": float(m["energy"]),
            "time_to_first_detection": int(ttfd),
            "poachers_entered": int(entered),
            "poachers_detected": int(m["poachers_detected"]),
            "signs_found": int(m["signs_found"]),
            "episode_length": int(self.t),
            "mode": int(self.mode),
        }

    def state(self) -> np.ndarray:
        """The global state (positions, batteries, poachers, leopards, coverage and signs by block, progress), in [-1, 1]."""
        self._require_episode("state")
        return global_state(self)

    def render(self) -> np.ndarray | None:
        """Draw the reserve with pygame: an RGB array in ``"rgb_array"`` mode, a window in ``"human"`` mode."""
        if self.render_mode is None:
            import gymnasium

            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'.")
            return None
        self._require_episode("render")
        from wildlife_reserve.reserve.rendering import ReserveRenderer

        if self._renderer is None:
            self._renderer = ReserveRenderer(self, self.render_mode, self.metadata["render_fps"])
        return self._renderer.draw()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
