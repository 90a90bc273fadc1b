"""Each agent's belief over the latent mode, from the whole episode so far, fused along the team's links.

:class:`BeliefTracker` keeps, per vector entry, the evidence ``e_k = sum_{j < t} log p(x_{j+1} | x_j, a_j, z = k)``
(its transition features' terms tempered by ``beta``, its readings' not: :class:`~sb3_emmarl.common.latent.model.
StepLikelihood`) that the entry's own transitions since its episode began give each component (one decoder call per
step: constant cost, no history re-read), plus, when the environment's plug-in counts readings (on the reserve:
where on the map signs, leopards and poachers were read), the plug-in's ``weight`` times the log-likelihood of each
new observation's counts under the component's count model (:mod:`~sb3_emmarl.common.latent.counts`), and the
belief ``q(z) = softmax(log pi + e + sum over teammates m of the newest own evidence of m known)``. Fusion follows
the links the environment reports: the reserve lists in ``infos[i]["heard_from"]`` the teammates whose messages
reached UAV ``i`` this step (after range, loss and jamming). A message carries what its sender knows, as the
reserve's messages carry its knowledge matrix: the sender's own evidence now and, for every other teammate, the
newest version of that teammate's own evidence the sender holds, with the step it dates from. The receiver keeps,
per teammate, whichever version is newest (evidence travels one hop per step, like the reserve's knowledge).
Each teammate's evidence enters a belief once, in one version: nothing is counted twice. No link, no fusion: with
``comm_loss=1`` every belief is the agent's own. Where the evidence of the UAVs is independent given the mode (each
reads its own noise), the fused belief is the exact posterior of all the evidence that reached the UAV, which is the
posterior of the whole team's evidence once every teammate's newest version has arrived.

How much arrived is the **evidence reach** (:meth:`BeliefTracker.evidence_reach`): the share of the team's transitions
since the episode began whose likelihood is in an entry's belief (1: the whole team's; ``1 / n`` for a UAV that heard
nobody). ``fusion="team"`` gives every entry every teammate's evidence at every step, whatever the links: the belief
of *centralised* inference (reach 1), an ablation to compare with, never the decentralised result.

:class:`BeliefWrapper` is the ``VecEnvWrapper`` that runs a tracker during training and evaluation and
appends the belief to every observation (terminal observations included), so that SB3's rollout and
replay buffers store exactly what the policy saw when it acted. ``EMPPO.predict`` runs the same tracker on
plain observations with the tracker's state passed through ``predict(obs, state, episode_start)``, as
RecurrentPPO passes its LSTM state (there are no ``infos`` there, hence no fusion).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from numba import njit
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.appended.wrapping import TERMINAL_OBSERVATION, AppendingVecEnvWrapper
from sb3_emmarl.common.latent.config import LatentConfig
from sb3_emmarl.common.latent.evidence import CountEvidence, evidence_of
from sb3_emmarl.common.latent.features import encode_actions
from sb3_emmarl.common.latent.layout import LatentLayout
from sb3_emmarl.common.latent.model import LatentModel, StepLikelihood
from sb3_emmarl.common.trust.validation import LATENT_RULES
from sb3_emmarl.common.vec_env import LINKS_KEY

#: Probabilities below this are 0 in the beliefs the policies read: sharp beliefs reached float32 subnormals
#: (1e-45 seen), and a matrix product over inputs holding subnormals runs at about two thirds of its speed on
#: this CPU (the reserve's risk channel had the same problem); the rows still sum to 1 within 1e-5.
BELIEF_FLOOR = 1e-6
#: The stamp of a teammate's evidence an entry has never heard of (below every clock value, relative ones included).
NEVER = -(2 ** 62)


@njit(cache=True)
def _merge_evidence(links: np.ndarray, evidence: np.ndarray, heard: np.ndarray, stamps: np.ndarray, started: np.ndarray,
                    clock: int) -> None:
    """:meth:`BeliefTracker.fuse`'s merge in place, simultaneous over the receivers (what a sender passes on is its
    table before this step's merge), in one compiled pass: some 20 small numpy calls cost about twice as much."""
    n, n_agents = links.shape
    best_sender = np.full((n, n_agents), -1, dtype=np.int64)
    best_stamp = stamps.copy()
    for r in range(n):
        base, own = r - r % n_agents, r % n_agents
        for s in range(n_agents):
            if not links[r, s]:
                continue
            for m in range(n_agents):
                stamp = clock if m == s else stamps[base + s, m]
                if m != own and stamp > best_stamp[r, m] and stamp > started[r]:
                    best_stamp[r, m], best_sender[r, m] = stamp, base + s
    fresh = heard.copy()
    for r in range(n):
        for m in range(n_agents):
            s = best_sender[r, m]
            if s >= 0:
                stamps[r, m] = best_stamp[r, m]
                fresh[r, m] = evidence[s] if s % n_agents == m else heard[s, m]
    heard[:] = fresh


class BeliefTracker:
    """Filtering posteriors ``q(z | o_{1:t}, a_{1:t-1})`` of ``n_entries`` vector entries.

    :param n_entries: vector entries (agents)
    :param n_components: ``K``
    :param feature_dim: ``d_x``
    :param action_dim: size of the encoded action
    :param agents_per_copy: agents per environment copy (entry ``i`` is agent ``i % agents_per_copy`` of copy
        ``i // agents_per_copy``); links only join agents of one copy
    :param model: the latent model (None: every belief is uniform, as in the no-latent ablation)
    :param likelihood_temperature: ``beta``, the factor on every transition's log-likelihood
    :param fusion: combine the evidence of the teammates heard from (True: along the links of the infos; ``"team"``:
        every teammate's, links or not, as centralised inference would; False: each belief is the agent's own)
    :param counter: the count evidence of the observations (the environment's plug-in's), used when the model has a
        count model
    """

    def __init__(self, n_entries: int, n_components: int, feature_dim: int, action_dim: int, *, agents_per_copy: int = 1,
                 model: LatentModel | None = None, likelihood_temperature: float = 1.0, fusion: bool | str = True,
                 counter: CountEvidence | None = None) -> None:
        self.n, self.k, self.agents_per_copy = n_entries, n_components, max(1, int(agents_per_copy))
        self.counter = counter
        self.likelihood_temperature, self.fusion = float(likelihood_temperature), LATENT_RULES["fusion"]("fusion", fusion)
        self.model = model
        self.evidence = np.zeros((n_entries, n_components))
        #: ``heard[i, m]``: the newest own evidence of teammate ``m`` that entry ``i`` knows, dated ``stamps[i, m]``
        #: (steps of this tracker's clock; ``NEVER``: nothing known); ``started[i]``: when ``i``'s episode began
        self.heard = np.zeros((n_entries, self.agents_per_copy, n_components))
        self.stamps = np.full((n_entries, self.agents_per_copy), NEVER, dtype=np.int64)
        self.started = np.zeros(n_entries, dtype=np.int64)
        self.clock = 0
        self.features = np.zeros((n_entries, feature_dim), dtype=np.float32)
        self.actions = np.zeros((n_entries, action_dim), dtype=np.float32)

    @property
    def model(self) -> LatentModel | None:
        """The latent model the beliefs come from (None: uniform beliefs)."""
        return self._model

    @model.setter
    def model(self, model: LatentModel | None) -> None:
        self._model = model
        self._likelihood = None if model is None else StepLikelihood(model)

    # ------------------------------------------------------------------ updates
    def start(self, indices: np.ndarray, features: np.ndarray) -> None:
        """New episodes for ``indices``: no evidence yet; ``features`` are those of their first observation."""
        self.evidence[indices] = 0.0
        self.heard[indices] = 0.0
        self.stamps[indices] = NEVER
        self.started[indices] = self.clock
        self.actions[indices] = 0.0
        self.features[indices] = features

    def set_actions(self, encoded_actions: np.ndarray) -> None:
        """The actions every entry just took (encoded), for the next transition."""
        self.actions[:] = encoded_actions

    def advance(self, indices: np.ndarray, next_features: np.ndarray, next_observations: np.ndarray | None = None) -> None:
        """Add the evidence of the transitions ``(x_t, a_t) -> x_{t+1}`` of ``indices`` (and of the reading counts of
        their ``next_observations``, when the model and the tracker have a count model)."""
        if len(indices) == 0:
            return
        if self._likelihood is not None:
            self.evidence[indices] += self._likelihood.log_likelihood(self.features[indices], self.actions[indices],
                                                                      next_features, self.likelihood_temperature)
            if next_observations is not None and self.counter is not None and self._likelihood.model.has_counts:
                counts = self._likelihood.count_log_likelihood(self.counter, next_observations, refresh=False)
                self.evidence[indices] += self.counter.weight * counts
        self.features[indices] = next_features

    def fuse(self, infos: Sequence[dict[str, Any]]) -> None:
        """Take from every message that reached an entry this step the newest evidence of each teammate it carries.

        A sender ``s`` passes its own evidence now and its table (``heard``, ``stamps``) as it was before this step's
        messages; receiver ``r`` replaces its entry of teammate ``m`` by the newest one sent, when that is newer than
        its own and dates from ``r``'s episode (never its own entry). This is the reserve's knowledge merge
        (``knowledge[r] = max(knowledge[r], knowledge[s])``) applied to the evidence.
        """
        self.clock += 1  # (one tick per step, fused or not: the clock also counts each entry's steps)
        if not self.fusion or self.agents_per_copy == 1:
            return
        if self.fusion == "team":  # every teammate, links or not (centralised inference)
            links = ~np.eye(self.agents_per_copy, dtype=np.bool_)[np.arange(self.n) % self.agents_per_copy]
        else:
            receivers: list[int] = []
            senders: list[int] = []
            for i, info in enumerate(infos):
                heard_from = info.get(LINKS_KEY) if isinstance(info, dict) else None
                if heard_from:
                    receivers += [i] * len(heard_from)
                    senders += heard_from
            if not receivers:
                return
            links = np.zeros((self.n, self.agents_per_copy), dtype=np.bool_)  # links[r, s]: teammate s reached entry r
            links[receivers, senders] = True
        _merge_evidence(links, self.evidence, self.heard, self.stamps, self.started, self.clock)

    def evidence_reach(self, indices: np.ndarray | slice = slice(None)) -> np.ndarray:
        """``(n,)``: the share of the team's transitions since the episode began whose likelihood is in each entry's
        belief (its own, and each teammate's up to the step of the newest version it holds); 1 before the first step
        and for a team of one.

        Counted in steps of :meth:`fuse`'s clock, which ticks once per environment step: the teammates of a copy
        begin their episodes together, so a teammate's version dated ``stamp`` holds ``stamp - started`` transitions.
        """
        own = (self.clock - self.started[indices]).astype(np.float64)
        stamps = self.stamps[indices]
        heard = np.where(stamps == NEVER, 0, stamps - self.started[indices][:, None]).clip(min=0).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            reach = (own + heard) / (self.agents_per_copy * own)
        return np.where(own > 0, reach, 1.0)

    # ------------------------------------------------------------------ beliefs
    def log_beliefs(self, indices: np.ndarray | slice = slice(None), refresh: bool = True) -> np.ndarray:
        """``log q(z)`` of ``indices`` ``(n, K)``: prior, own evidence and the evidence last heard from teammates.

        :param refresh: read the model's current prior (False: the caller has just advanced the tracker, which
            read it, and nothing has written to the model since: the wrapper's step saves a check per step)
        """
        evidence = self.evidence[indices] + self.heard[indices].sum(axis=1)
        if self._likelihood is not None:
            evidence = evidence + self._likelihood.prior(refresh)
        evidence -= evidence.max(axis=1, keepdims=True)  # a log-softmax (scipy's costs 3x as much on 40 rows)
        return evidence - np.log(np.exp(evidence).sum(axis=1, keepdims=True))

    def beliefs(self, indices: np.ndarray | slice = slice(None), refresh: bool = True) -> np.ndarray:
        """``q(z)`` of ``indices`` ``(n, K)`` as float32 probabilities, those below :data:`BELIEF_FLOOR` as 0
        (``refresh`` as in :meth:`log_beliefs`)."""
        beliefs = np.exp(self.log_beliefs(indices, refresh)).astype(np.float32)
        beliefs[beliefs < BELIEF_FLOOR] = 0.0
        return beliefs

    # ------------------------------------------------------------------ state for predict()
    def get_state(self) -> np.ndarray:
        """Everything the tracker holds, one row per entry (the ``state`` of ``EMPPO.predict``; the stamps relative to
        the tracker's clock, so that a state restores into any tracker)."""
        stamps = np.where(self.stamps == NEVER, NEVER, self.stamps - self.clock)
        return np.concatenate([self.evidence, self.heard.reshape(self.n, -1), stamps, (self.started - self.clock)[:, None],
                               self.features, self.actions], axis=1).astype(np.float64)

    def set_state(self, state: np.ndarray) -> None:
        """Restore a :meth:`get_state` array."""
        state = np.asarray(state, dtype=np.float64)
        expected = self.get_state().shape
        if state.shape != expected:
            raise ValueError(f"the belief state must have shape {expected} (from the previous predict call), "
                             f"got {state.shape}")
        k, h, a, d_x = self.k, self.heard[0].size, self.agents_per_copy, self.features.shape[1]
        self.evidence[:] = state[:, :k]
        self.heard[:] = state[:, k:k + h].reshape(self.heard.shape)
        stamps = state[:, k + h:k + h + a].astype(np.int64)
        self.stamps[:] = np.where(stamps == NEVER, NEVER, stamps + self.clock)
        self.started[:] = state[:, k + h + a].astype(np.int64) + self.clock
        at = k + h + a + 1
        self.features[:] = state[:, at:at + d_x]
        self.actions[:] = state[:, at + d_x:]


def agents_per_copy(venv: VecEnv) -> int:
    """Agents per environment copy of a vector environment (the reserve's parameter-sharing one), else 1."""
    return int(getattr(venv, "agents_per_copy", 1))


class BeliefWrapper(AppendingVecEnvWrapper):
    """Append each entry's belief ``q(z | o_{1:t}, a_{1:t-1})`` (``n_components`` floats) to its observation.

    Until :meth:`attach` hands it a latent model, every belief is uniform.

    :param venv: the vector environment (flat ``Box`` observations)
    :param n_components: ``K``
    """

    def __init__(self, venv: VecEnv, n_components: int) -> None:
        n_components = LATENT_RULES["n_components"]("n_components", n_components)
        space = venv.observation_space
        if not isinstance(space, spaces.Box) or len(space.shape) != 1:  # (before the evidence reads the space)
            raise ValueError(f"the latent algorithms need flat Box observations, got {space}")
        #: the environment's evidence (:func:`~sb3_emmarl.common.latent.evidence.evidence_of`): its features, the
        #: specification saved with a model, and its count evidence (None: the transition mixture alone)
        self.evidence = evidence_of(venv)
        self.feature_fn, self.evidence_spec = self.evidence.features, self.evidence.spec
        self.feature_dim, self.counter = self.evidence.feature_dim, self.evidence.counts
        self.encode_action, self.action_dim = encode_actions(venv.action_space)
        self.obs_dim, self.n_components = int(space.shape[0]), int(n_components)
        super().__init__(venv, np.zeros(n_components, np.float32), np.ones(n_components, np.float32))
        self.tracker = BeliefTracker(self.num_envs, n_components, self.feature_dim, self.action_dim,
                                     agents_per_copy=agents_per_copy(venv), counter=self.counter)

    def layout(self, decoder_hidden: tuple[int, ...], reading_counts: bool = True) -> LatentLayout:
        """The latent layout of a model of this wrapper's beliefs: its sizes, the evidence's count model (with
        ``reading_counts``) and readings.

        :param decoder_hidden: the decoder trunk's hidden sizes
        :param reading_counts: give the model the evidence's count model, if it has one
        """
        counter = self.counter if reading_counts else None
        return LatentLayout(self.obs_dim, self.feature_dim, self.action_dim, self.n_components, tuple(decoder_hidden),
                            count_channels=counter.n_channels if counter else 0,
                            count_bins=counter.n_bins if counter else 0, reading_features=self.evidence.readings)

    def attach(self, model: LatentModel | None, config: LatentConfig) -> None:
        """Compute beliefs with ``model`` and ``config``'s likelihood temperature and fusion from now on (evidence
        gathered so far is kept); the record was validated when it was made."""
        if model is not None and model.n_components != self.n_components:
            raise ValueError(f"the latent model has {model.n_components} components, the wrapper {self.n_components}")
        tracker = self.tracker
        tracker.model, tracker.likelihood_temperature, tracker.fusion = model, config.likelihood_temperature, config.fusion

    def get_state(self) -> np.ndarray:
        """The beliefs' state between steps (for checkpoints that resume mid-episode)."""
        return self.tracker.get_state()

    def set_state(self, state: np.ndarray) -> None:
        """Restore :meth:`get_state`."""
        self.tracker.set_state(state)

    def _reset_extra(self, observations: np.ndarray) -> np.ndarray:
        self.reset_infos = getattr(self.venv, "reset_infos", self.reset_infos)
        self.tracker.start(np.arange(self.num_envs), self.feature_fn(observations))
        return self.tracker.beliefs()

    def step_async(self, actions: np.ndarray) -> None:
        self.tracker.set_actions(self.encode_action(actions))
        self.venv.step_async(actions)

    def _step_extra(self, observations: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
                    ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        features = self.feature_fn(observations)
        done_idx = np.flatnonzero(dones)
        tracker = self.tracker
        following, seen = features, observations
        if len(done_idx):  # the episode's last transition leads to its terminal observation
            terminal = np.stack([infos[i][TERMINAL_OBSERVATION] for i in done_idx])
            following, seen = features.copy(), np.array(observations, copy=True)
            following[done_idx] = self.feature_fn(terminal)
            seen[done_idx] = terminal
        tracker.advance(np.arange(self.num_envs), following, seen if tracker.counter is not None else None)
        tracker.fuse(infos)
        ended: dict[int, np.ndarray] = {}
        if len(done_idx):
            ended = dict(zip(done_idx.tolist(), tracker.beliefs(done_idx, refresh=False)))
            tracker.start(done_idx, features[done_idx])
        return tracker.beliefs(refresh=False), ended
