"""The history each agent's latent encoder reads, supplied through the observation.

:class:`HistoryWrapper` is a ``VecEnvWrapper`` that appends to every observation a window of the
last ``history_length`` steps of that vector entry: compact features ``x`` of the observation, the
previous action (one-hot for discrete actions), the previous reward and a "valid" flag (0 for the
zero padding before an episode's start). SB3's rollout and replay buffers store the augmented
observation unchanged, so the history reaches the encoder at collection and at update time alike.

Window slot ``H - 1`` is the newest: ``(x_t, a_{t-1}, r_{t-1}, 1)`` for the observation ``o_t``.
Terminal observations in ``infos`` are augmented the same way, so bootstrapping and replay see
the history too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, unwrap_vec_wrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

#: Observations larger than this are reduced to this many compact features by a fixed projection.
MAX_GENERIC_FEATURES = 32

FeatureFn = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class HistoryLayout:
    """Where the parts of an augmented observation live (all ints, saved with the model).

    :param obs_dim: size of the original (flat) observation
    :param history_length: steps in the window (``H``)
    :param feature_dim: compact features per step (``d_x``)
    :param action_dim: size of the encoded action (one-hot size for discrete actions)
    """

    obs_dim: int
    history_length: int
    feature_dim: int
    action_dim: int

    @property
    def step_dim(self) -> int:
        """Size of one window slot: features, action, reward, valid flag."""
        return self.feature_dim + self.action_dim + 2

    @property
    def total_dim(self) -> int:
        return self.obs_dim + self.history_length * self.step_dim

    def split(self, observations):
        """Split augmented observations ``(..., total_dim)`` into the original part and the window ``(..., H, step_dim)``."""
        raw = observations[..., : self.obs_dim]
        window = observations[..., self.obs_dim:].reshape(*observations.shape[:-1], self.history_length, self.step_dim)
        return raw, window

    def posterior_columns(self, n_components: int) -> slice:
        """Where a precomputed posterior is written in an augmented observation: over the start of its window
        (used only once the window has been read, see ``LatentAlgorithmMixin.write_posterior``)."""
        return slice(self.obs_dim, self.obs_dim + n_components)

    def slot_parts(self, window):
        """Split a window ``(..., H, step_dim)`` into features, actions, rewards and the valid flag."""
        d_x, d_a = self.feature_dim, self.action_dim
        return window[..., :d_x], window[..., d_x:d_x + d_a], window[..., d_x + d_a], window[..., d_x + d_a + 1]


def reserve_features(layout: dict) -> FeatureFn:
    """Compact features of the reserve's observation (26 by default).

    Own position, velocity, battery and progress (6); counts of poacher readings, leopard readings and
    other UAVs in the window, and the share of readings on its outer ring (4); the belief map pooled 2 x 2.

    :param layout: the reserve's ``observation_layout`` (name -> (slice, shape))
    """
    window_part, window_shape = layout["window"]
    own_part = layout["own"][0]
    belief_part, belief_shape = layout["belief"]
    channels, width = window_shape[0], window_shape[1]
    r = width // 2
    ring = np.maximum(*np.abs(np.indices((width, width)) - r)) == r
    pooled = (belief_shape[0] + 1) // 2

    def features(obs: np.ndarray) -> np.ndarray:
        n = obs.shape[0]
        window = obs[:, window_part].reshape(n, channels, width, width)
        readings = window[:, 3:5] > 0.5  # poacher and leopard channels
        counts = readings.sum(axis=(2, 3)).astype(np.float32)
        outer = readings[:, :, ring].sum(axis=(1, 2)) / np.maximum(counts.sum(axis=1), 1.0)
        uavs = (window[:, 5] > 0.5).sum(axis=(1, 2))
        belief = obs[:, belief_part].reshape(n, *belief_shape)
        padded = np.zeros((n, 2 * pooled, 2 * pooled), dtype=np.float32)
        padded[:, : belief_shape[0], : belief_shape[1]] = belief
        pooled_belief = padded.reshape(n, pooled, 2, pooled, 2).max(axis=(2, 4)).reshape(n, -1)
        return np.concatenate([obs[:, own_part], np.minimum(counts, 5.0) / 5.0, outer[:, None],
                               np.minimum(uavs, 5.0)[:, None] / 5.0, pooled_belief], axis=1).astype(np.float32)

    return features


def generic_features(obs_dim: int, seed: int = 0) -> tuple[FeatureFn, int]:
    """The observation itself when small, else a fixed random projection to :data:`MAX_GENERIC_FEATURES` dims."""
    if obs_dim <= MAX_GENERIC_FEATURES:
        return (lambda obs: obs.astype(np.float32)), obs_dim
    projection = np.random.default_rng(seed).standard_normal((obs_dim, MAX_GENERIC_FEATURES)) / np.sqrt(obs_dim)
    projection = projection.astype(np.float32)
    return (lambda obs: obs.astype(np.float32) @ projection), MAX_GENERIC_FEATURES


def default_features(venv: VecEnv) -> tuple[FeatureFn, int]:
    """The reserve's compact features when ``venv`` is the reserve, otherwise :func:`generic_features`."""
    obs_dim = int(np.prod(venv.observation_space.shape))
    try:
        layout = venv.get_attr("observation_layout", indices=[0])[0]
    except (AttributeError, NotImplementedError):
        layout = None
    if isinstance(layout, dict) and {"window", "own", "belief"} <= set(layout):
        fn = reserve_features(layout)
        return fn, fn(np.zeros((1, obs_dim), dtype=np.float32)).shape[1]
    return generic_features(obs_dim)


def encode_actions(action_space: spaces.Space) -> tuple[Callable[[np.ndarray], np.ndarray], int]:
    """How actions enter the window: one-hot (``Discrete``, ``MultiDiscrete``) or as they are (``Box``)."""
    if isinstance(action_space, spaces.Discrete):
        n = int(action_space.n)
        return (lambda a: np.eye(n, dtype=np.float32)[np.asarray(a, dtype=np.int64).reshape(-1) - action_space.start]), n
    if isinstance(action_space, spaces.MultiDiscrete):
        sizes = action_space.nvec.ravel().astype(np.int64)
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])

        def one_hot(a: np.ndarray) -> np.ndarray:
            a = np.asarray(a, dtype=np.int64).reshape(len(a), -1)
            out = np.zeros((len(a), int(sizes.sum())), dtype=np.float32)
            out[np.arange(len(a))[:, None], offsets + a] = 1.0
            return out

        return one_hot, int(sizes.sum())
    if isinstance(action_space, spaces.Box):
        dim = int(np.prod(action_space.shape))
        return (lambda a: np.asarray(a, dtype=np.float32).reshape(len(a), dim)), dim
    raise ValueError(f"HistoryWrapper supports Discrete, MultiDiscrete and Box actions, not {action_space}")


class HistoryWrapper(VecEnvWrapper):
    """Append each entry's recent history to its (flat ``Box``) observation.

    :param venv: the vector environment
    :param history_length: steps ``H`` in the window, >= 1
    :param feature_fn: compact features of a batch of observations ``(n, obs_dim) -> (n, d_x)``; None picks
        :func:`default_features` (the reserve's own when it is the reserve)
    :param feature_dim: ``d_x`` (needed with a custom ``feature_fn``)
    """

    def __init__(self, venv: VecEnv, history_length: int = 8, feature_fn: FeatureFn | None = None,
                 feature_dim: int | None = None) -> None:
        if isinstance(history_length, bool) or not isinstance(history_length, (int, np.integer)) or history_length < 1:
            raise ValueError(f"history_length must be an int >= 1, got {history_length!r}")
        space = venv.observation_space
        if not isinstance(space, spaces.Box) or len(space.shape) != 1:
            raise ValueError(f"HistoryWrapper needs flat Box observations, got {space}")
        if feature_fn is None:
            feature_fn, feature_dim = default_features(venv)
        elif feature_dim is None:
            raise ValueError("a custom feature_fn needs its feature_dim")
        self.feature_fn = feature_fn
        self.encode_action, action_dim = encode_actions(venv.action_space)
        self.layout = HistoryLayout(int(space.shape[0]), int(history_length), int(feature_dim), action_dim)
        low = np.concatenate([space.low, np.full(self.layout.total_dim - space.shape[0], -np.inf, np.float32)])
        high = np.concatenate([space.high, np.full(self.layout.total_dim - space.shape[0], np.inf, np.float32)])
        super().__init__(venv, observation_space=spaces.Box(low, high, dtype=np.float32))
        self.window = np.zeros((self.num_envs, history_length, self.layout.step_dim), dtype=np.float32)

    def _start(self, indices: np.ndarray, observations: np.ndarray) -> None:
        """Empty the windows of ``indices`` and put the first observation's features in the newest slot."""
        self.window[indices] = 0.0
        self.window[indices, -1, : self.layout.feature_dim] = self.feature_fn(observations)
        self.window[indices, -1, -1] = 1.0

    def _augment(self, observations: np.ndarray, window: np.ndarray) -> np.ndarray:
        return np.concatenate([observations.reshape(len(observations), -1).astype(np.float32),
                               window.reshape(len(window), -1)], axis=1)

    def reset(self) -> VecEnvObs:
        observations = self.venv.reset()
        self._start(np.arange(self.num_envs), observations)
        return self._augment(observations, self.window)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions
        self.venv.step_async(actions)

    def step_wait(self) -> VecEnvStepReturn:
        observations, rewards, dones, infos = self.venv.step_wait()
        d_x, d_a = self.layout.feature_dim, self.layout.action_dim
        done_idx = np.flatnonzero(dones)
        # The step's new slot: features of the observation that follows it (the terminal one at an end).
        following = observations.copy() if len(done_idx) else observations
        for i in done_idx:
            following[i] = infos[i]["terminal_observation"]
        self.window = np.roll(self.window, -1, axis=1)
        self.window[:, -1, :d_x] = self.feature_fn(following)
        self.window[:, -1, d_x:d_x + d_a] = self.encode_action(self._actions)
        self.window[:, -1, d_x + d_a] = rewards
        self.window[:, -1, -1] = 1.0
        if len(done_idx):
            for i in done_idx:
                infos[i] = dict(infos[i])
                infos[i]["terminal_observation"] = self._augment(following[i:i + 1], self.window[i:i + 1])[0]
            self._start(done_idx, observations[done_idx])
        return self._augment(observations, self.window), rewards, dones, infos


def find_history_wrapper(venv: VecEnv) -> HistoryWrapper | None:
    """The :class:`HistoryWrapper` inside a stack of vector wrappers, if any."""
    return unwrap_vec_wrapper(venv, HistoryWrapper)
