"""
# Zone Patrol

| Import             | `from wildlife_reserve import zone_patrol_v1`                           |
|--------------------|-------------------------------------------------------------------------|
| Actions            | Discrete                                                                |
| Parallel API       | Yes                                                                     |
| Manual control     | No                                                                      |
| Agents             | `agents= ['uav_0', 'uav_1', 'uav_2', 'uav_3']` (default `n_uavs=4`)     |
| Action shape       | `Discrete(10)`: `move + 5 * sensor`                                     |
| Observation shape  | `(3 * (2r + 1)^2 + 4 + 4,)`: 83 by default (`zone_cue=0`: 4 fewer; `agent_ids`: n more, `told`: 8) |
| Observation values | [-1, 1]                                                                 |
| State shape        | `(2 n_uavs + 2 grid_size^2 + 1,)`: 1577 by default                      |

A small team task where a hidden mode decides the best action. Each episode draws a mode, a **zone** (one of four
corner zones of `zone_size x zone_size` cells) x a **weather** (clear or fog); the UAVs never observe it
(`infos[agent]["mode"]`, `2 * zone + weather`, is for evaluation only). Intruders appear in the mode's zone only
(each step with chance `spawn_prob`), wander in it and escape after `intruder_life` steps unless a UAV detects
them. The zones lie far apart (crossing from the centre to a zone takes about a third of an episode), so a team that
does not know the zone must split and converge on evidence, while a team told it stacks in it. The weather decides
which sensor works: the wide one (reach `wide_radius`) sees well in clear weather and almost nothing in fog; the
narrow one (reach `narrow_radius`) sees alike in both. A scripted team told the mode earns 1.5 times what the best
blind scripted team earns, though that team shares everything its UAVs see (`benchmarks/zone_patrol_gate.py`).

The evidence builds up: intruders leave tracks that fade after `track_life` steps, and older tracks lie in the zone
at the start; the visibility reading (1 in clear weather, 0 in fog, plus noise of deviation `visibility_noise`) shows
the weather over many steps, not in one. Every UAV also reads, each step and wherever it is, a faint signal of the
zone (`zone_cue`, radio chatter: per zone, `zone_cue` for the mode's zone plus standard normal noise): its evidence
grows as `zone_cue * sqrt(steps)`, so a team that integrates the readings over time can infer the zone without
searching, which a memoryless policy cannot. One UAV's readings tell the zone by mid-episode far less often than the
whole team's (docs/zone_patrol.md): a UAV's belief is worth what it pools from its teammates, whose messages reach it
within `comm_range` (relayed one hop per step).

### Observations
Per UAV, a flat float32 vector: an egocentric `(2r + 1) x (2r + 1)` window (`r = window_radius`) of three channels
(tracks, as their remaining life over `track_life`, -1 off the grid; this UAV's detections this step; teammates),
then its own position (row, column, scaled to [-1, 1]), the visibility reading (clipped to [-3, 4], over 4) and the
episode's progress (`t / max_cycles`); the four zone readings (clipped to [-4, 4], over 4; none with `zone_cue=0`); with
`agent_ids=True`, the one-hot of the UAV's index in the team (EPyMARL's
`obs_agent_id`: with parameter sharing, what lets UAVs that see alike split over the zones); with `told=True`, the
one-hot of the mode last.

### Actions
`move + 5 * sensor`, with move in {stay, up, down, left, right} and sensor in {wide, narrow}.

### Rewards
One shared team reward per step: +1 per intruder detected, minus `escape_cost` per intruder that escaped.

### Infos
`infos[agent]["mode"]` (the hidden mode, for evaluation), `infos[agent]["heard_from"]` (the indices of the teammates
within `comm_range`, whose messages reach this UAV: the same meaning as the reserve's, so EM's fusion works
unchanged) and, on the last step, `infos[agent]["metrics"]` (team reward, detections, escapes, intruders, detection
rate, mode).

### Arguments
Every field of :class:`~wildlife_reserve.zone_patrol.world.ZonePatrolConfig`, by keyword; a bad value raises
`ValueError` naming the argument. `reset(seed, options={"mode": m})` fixes the mode of the episode.

### Version History
* v1: zone readings on by default (`zone_cue=0.24`, chosen on the gate) and links across half the grid
  (`comm_range=None`: 14 cells on the default grid, chosen on the evidence reach), so that the team's evidence tells
  the zone by mid-episode and reaches every UAV; every other constant as v0's
* v0: `zone_cue=0`, `comm_range=4`; still importable (`zone_patrol_v0`, zoo id `ZonePatrol-v0`), its episodes as
  before; what each sb3-emmarl release changed in either version is in CHANGELOG.md
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

from wildlife_reserve.utils.checks import check_action_dict, check_agent, check_int, check_options, check_seed, discrete_action
from wildlife_reserve.utils.extras import requires
from wildlife_reserve.zone_patrol.world import N_MOVES, N_SENSORS, N_ZONES, ZonePatrolConfig, ZonePatrolWorld

#: The render modes (``metadata["render_modes"]``).
RENDER_MODES = ("human", "rgb_array")
#: The keys ``reset(options=...)`` takes.
RESET_OPTIONS = ("mode",)
#: The current version (``zone_patrol_v1``), whose defaults are :class:`ZonePatrolConfig`'s.
VERSION = 1
#: Each former version's defaults that differ from the current version's (its module passes them under the caller's
#: arguments, so that its episodes stay as they were).
FORMER_DEFAULTS: dict[int, dict[str, Any]] = {0: {"zone_cue": 0.0, "comm_range": 4}}


def env(version: int = VERSION, **kwargs: Any) -> wrappers.OrderEnforcingWrapper:
    """The AEC form, with PettingZoo's order-enforcing wrapper."""
    return wrappers.OrderEnforcingWrapper(raw_env(version, **kwargs))


def raw_env(version: int = VERSION, **kwargs: Any) -> parallel_to_aec_wrapper:
    """The AEC form (PettingZoo's conversion of the parallel environment)."""
    return parallel_to_aec_wrapper(parallel_env(version, **kwargs))


def parallel_env(version: int = VERSION, **kwargs: Any) -> ZonePatrolParallelEnv:
    """The parallel environment (keyword arguments: :class:`~wildlife_reserve.zone_patrol.world.ZonePatrolConfig`;
    ``version``: the version whose defaults apply, as the modules ``zone_patrol_v0`` and ``zone_patrol_v1`` set it)."""
    return ZonePatrolParallelEnv(version=version, **kwargs)


class ZonePatrolParallelEnv(ParallelEnv):
    """ZonePatrol as a PettingZoo ``ParallelEnv`` (one copy of :class:`ZonePatrolWorld`; see the module's card).

    :param render_mode: None, ``"rgb_array"`` (an RGB image of the grid) or ``"human"`` (the image in a pygame window)
    :param version: the version whose defaults apply (:data:`VERSION`, or one of :data:`FORMER_DEFAULTS`)
    :param kwargs: :class:`~wildlife_reserve.zone_patrol.world.ZonePatrolConfig` fields
    """

    metadata = {"name": f"zone_patrol_v{VERSION}", "render_modes": list(RENDER_MODES), "is_parallelizable": True,
                "render_fps": 10}

    def __init__(self, render_mode: str | None = None, version: int = VERSION, **kwargs: Any) -> None:
        if render_mode not in (None, *RENDER_MODES):
            raise ValueError(f"render_mode must be None or one of {list(RENDER_MODES)}, got {render_mode!r}")
        if isinstance(version, bool) or version not in (VERSION, *FORMER_DEFAULTS):
            raise ValueError(f"version must be one of {sorted((VERSION, *FORMER_DEFAULTS))}, got {version!r}")
        self.version = int(version)
        self.metadata = {**self.metadata, "name": f"zone_patrol_v{self.version}"}
        self.config = ZonePatrolConfig.from_kwargs(**{**FORMER_DEFAULTS.get(self.version, {}), **kwargs})
        self.render_mode = render_mode
        self.possible_agents = [f"uav_{i}" for i in range(self.config.n_uavs)]
        self.agents: list[str] = []
        self.world = ZonePatrolWorld(self.config, 1)
        self._rng, _ = seeding.np_random(None)
        self._started = False
        self._window: Any = None
        size = self.config.state_dim
        self.state_space = spaces.Box(-1.0, 1.0, (size,), np.float32)

    @functools.cache  # noqa: B019 (PettingZoo's habit: one space object per agent)
    def observation_space(self, agent: str) -> spaces.Box:
        check_agent(agent, self.possible_agents)
        return spaces.Box(-1.0, 1.0, (self.config.obs_dim,), np.float32)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Discrete:
        check_agent(agent, self.possible_agents)
        return spaces.Discrete(N_MOVES * N_SENSORS)

    @property
    def obs_dim(self) -> int:
        """Size of one UAV's observation (the array API's, as the reserve's)."""
        return self.config.obs_dim

    @property
    def zone_map(self) -> dict[str, Any]:
        """Where the zones lie and where an observation holds the window and the UAV's cell, as plain values: the map
        a reader of the evidence needs to tell in which zone a track was seen (EM's zone features,
        :func:`sb3_emmarl.common.latent.zone_evidence.zone_features`)."""
        cfg, cells = self.config, self.config.window_cells
        return {"grid_size": cfg.grid_size, "zone_size": cfg.zone_size, "window_radius": cfg.window_radius,
                "zone_origins": cfg.zone_origins().tolist(), "tracks": [0, cells], "detections": [cells, 2 * cells],
                "own": [3 * cells, 3 * cells + 2], "visibility": 3 * cells + 2,
                "cues": [3 * cells + 4, 3 * cells + 4 + N_ZONES] if cfg.zone_cue else None}

    @property
    def mode(self) -> int:
        """The hidden mode of the current episode (for evaluation)."""
        return int(self.world.modes[0])

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start an episode.

        :param seed: an int >= 0 seeds the episode's draws (and later unseeded resets'), or None
        :param options: ``{"mode": int}`` fixes the hidden mode for this episode; a misspelling of it is refused,
            another key is named in a warning and ignored (:func:`~wildlife_reserve.utils.checks.check_options`)
        :raise ValueError: for a bad seed or option, before anything changes
        """
        seed = check_seed(seed)
        given = check_options(options, RESET_OPTIONS)
        mode = None
        if "mode" in given:
            mode = np.array([check_int("options['mode']", given["mode"], 0, self.config.n_modes - 1)])
        if seed is not None:
            self._rng, _ = seeding.np_random(seed)
        self.world.reset(self._rng, mode)
        self.agents = list(self.possible_agents)
        self._started = True
        observations = self.world.observations()[0]
        links = self.world.links()[0]
        infos = {a: {"mode": self.mode, "heard_from": links[i]} for i, a in enumerate(self.agents)}
        return {a: observations[i] for i, a in enumerate(self.agents)}, infos

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        """Advance every UAV one step.

        :param actions: an int in ``[0, 10)`` per live agent (one left out takes action 0: stay, first sensor); a key
            that is no live agent is refused
        """
        self._check_running()
        check_action_dict(actions, self.agents)
        joint = np.zeros(self.config.n_uavs, dtype=np.int64)
        for i, agent in enumerate(self.agents):
            joint[i] = discrete_action(agent, actions.get(agent, 0), N_MOVES * N_SENSORS)
        agents = list(self.agents)
        observations, rewards, terminated, truncated, info, heard = self.step_arrays(joint)
        infos = {a: {**info, "heard_from": heard[i]} for i, a in enumerate(agents)}
        return ({a: observations[i] for i, a in enumerate(agents)}, {a: float(rewards[i]) for i, a in enumerate(agents)},
                {a: terminated for a in agents}, {a: truncated for a in agents}, infos)

    def step_arrays(self, actions: np.ndarray, out: np.ndarray | None = None) -> tuple[
            np.ndarray, np.ndarray, bool, bool, dict[str, Any], list[tuple[int, ...]]]:
        """:meth:`step` on arrays, in agent order, without the per-agent dictionaries (the reserve's array API, which
        the batched vector environment, ``sb3_emmarl.common.vec_env.ReserveVecEnv``, steps).

        :param actions: ``(n_uavs,)`` ints in ``[0, 10)``
        :param out: a float32 ``(n_uavs, obs_dim)`` array to write the observations into (returned), or None
        :return: observations, rewards ``(n_uavs,)`` (the team reward, every UAV alike), terminated, truncated, the info
            every UAV shares (``mode``, and ``metrics`` on the last step) and each UAV's ``heard_from``
        """
        self._check_running()
        joint = np.asarray(actions)
        n = self.config.n_uavs
        if joint.shape != (n,) or joint.dtype.kind not in "iu" or not 0 <= joint.min() <= joint.max() < N_MOVES * N_SENSORS:
            raise ValueError(f"actions must be {n} ints in [0, {N_MOVES * N_SENSORS - 1}], got {actions!r}")
        if out is not None and (out.shape != (n, self.obs_dim) or out.dtype != np.float32):
            raise ValueError(f"out must be a float32 array of shape {(n, self.obs_dim)}, got {out.dtype} {out.shape}")
        reward = float(self.world.step(joint[None], self._rng)[0])
        observations = self.world.observations()[0]
        if out is not None:
            out[:] = observations
            observations = out
        done = self.world.t >= self.config.max_cycles
        info: dict[str, Any] = {"mode": self.mode}
        if done:
            info["metrics"] = self.world.metrics()[0]
            self.agents = []
        return observations, np.full(n, reward), False, done, info, self.world.links()[0]

    def _check_running(self) -> None:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        if not self.agents:
            raise RuntimeError("the episode is over: call reset()")

    def state(self) -> np.ndarray:
        if not self._started:
            raise RuntimeError("call reset() before state()")
        return self.world.states()[0]

    def render(self) -> np.ndarray | None:
        """An RGB image of the grid (``rgb_array``; ``human`` shows it in a pygame window and returns None): zones
        grey, tracks brown, intruders red, UAVs blue."""
        if self.render_mode is None:
            return None
        if not self._started:
            raise RuntimeError("call reset() before render()")
        image = self._image()
        if self.render_mode == "rgb_array":
            return image
        with requires("pygame", "render", "ZonePatrol's human rendering"):
            import pygame

        if self._window is None:
            pygame.init()
            self._window = pygame.display.set_mode(image.shape[1::-1])
        self._window.blit(pygame.surfarray.make_surface(image.swapaxes(0, 1)), (0, 0))
        pygame.event.pump()
        pygame.display.flip()
        return None

    def _image(self) -> np.ndarray:
        cfg, world = self.config, self.world
        image = np.full((cfg.grid_size, cfg.grid_size, 3), 255, dtype=np.uint8)
        for top, left in cfg.zone_origins():
            image[top:top + cfg.zone_size, left:left + cfg.zone_size] = 220
        image[world.tracks[0] > 0] = (170, 120, 60)
        alive = world.alive[0]
        image[world.intruders[0, alive, 0], world.intruders[0, alive, 1]] = (220, 30, 30)
        image[world.positions[0, :, 0], world.positions[0, :, 1]] = (30, 60, 220)
        return np.kron(image, np.ones((8, 8, 1), dtype=np.uint8))

    def close(self) -> None:
        if self._window is not None:
            import pygame

            pygame.display.quit()
            self._window = None
