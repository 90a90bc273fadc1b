"""The E-step between rollouts, and the callback that runs it (Algorithm 2, line 11).

:func:`transitions_from_pairs` turns pairs of consecutive augmented observations (from a rollout
buffer or a replay buffer) into the E-step's data: the history ``h_t``, ``x_t``, ``a_t`` and the
target ``(x_{t+1}, r_t)``. :class:`EStep` keeps the latest few rollouts' data, fits the encoder and
decoder by maximising the ELBO with Adam, then sets the prior ``pi`` to the mean responsibilities.
:class:`EMCallback` calls it at the end of each rollout; the M-step is the algorithm's own update.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_emmarl.common.latent.history import HistoryLayout
from sb3_emmarl.common.latent.model import LatentModel

FIELDS = ("window", "next_slot", "groups")


@dataclass
class LatentBatch:
    """E-step data: the history ``window`` ``h_t`` ``(N, H, step_dim)``, the ``next_slot`` ``(N, step_dim)``
    (``x_{t+1}``, ``a_t``, ``r_t``) and ``groups`` (agents of one reserve copy at one step share a group id)."""

    window: th.Tensor
    next_slot: th.Tensor
    groups: th.Tensor

    def __len__(self) -> int:
        return len(self.window)

    @staticmethod
    def cat(batches: list[LatentBatch]) -> LatentBatch:
        offset, groups = 0, []
        for batch in batches:  # keep group ids distinct across rollouts
            groups.append(batch.groups + offset)
            offset += int(batch.groups.max()) + 1 if len(batch) else 0
        return LatentBatch(th.cat([b.window for b in batches]), th.cat([b.next_slot for b in batches]), th.cat(groups))


def transitions_from_pairs(layout: HistoryLayout, observations: np.ndarray, next_observations: np.ndarray,
                           groups: np.ndarray, device: th.device | str = "cpu") -> LatentBatch:
    """E-step samples from augmented observations ``o_t`` and ``o_{t+1}`` of the same entry (``(N, total_dim)``):
    ``h_t`` is ``o_t``'s window, and the newest slot of ``o_{t+1}``'s window holds ``x_{t+1}``, ``a_t`` and ``r_t``."""
    _, window = layout.split(observations)
    _, next_window = layout.split(next_observations)

    def tensor(x: np.ndarray) -> th.Tensor:
        return th.as_tensor(np.ascontiguousarray(x), dtype=th.float32, device=device)

    return LatentBatch(tensor(window), tensor(next_window[:, -1]), th.as_tensor(groups, dtype=th.long, device=device))


def team_groups(steps: np.ndarray, entries: np.ndarray, n_envs: int, agents_per_copy: int) -> np.ndarray:
    """Group ids of ``(step, vector entry)`` pairs: the agents of one reserve copy at one step share one."""
    return steps * max(1, n_envs // agents_per_copy) + entries // agents_per_copy


def transitions_from_rollout(layout: HistoryLayout, observations: np.ndarray, episode_starts: np.ndarray,
                             agents_per_copy: int, device: th.device | str = "cpu") -> LatentBatch:
    """E-step samples from an on-policy rollout buffer (``(n_steps, n_envs, total_dim)``), skipping episode ends."""
    t, env = np.nonzero(episode_starts[1:] == 0)  # o_{t+1} follows o_t within one episode
    groups = team_groups(t, env, episode_starts.shape[1], agents_per_copy)
    return transitions_from_pairs(layout, observations[t, env], observations[t + 1, env], groups, device)


class EStep:
    """Fit the encoder and decoder on recent data by maximising the ELBO, then set ``pi`` in closed form.

    :param latent_model: the latent model (its prior is updated in place)
    :param learning_rate: Adam learning rate of the encoder and decoder
    :param n_epochs: passes over the data per E-step
    :param batch_size: minibatch size
    :param window: data sets kept: the one added for this E-step and the ``window - 1`` added for the E-steps
        before it (the algorithms add one rollout per E-step, so with ``e_step_interval > 1`` the rollouts
        collected between E-steps never reach it)
    :param estimator: ``"enumerate"`` or ``"gumbel"``
    :param temperature: initial Gumbel-softmax temperature
    :param min_temperature: floor of the annealed temperature
    :param anneal_rate: the temperature is ``max(min_temperature, temperature * exp(-anneal_rate * n_e_steps))``
    :param team_pooling: pool the agents of one copy and step into a team posterior during training
    :param max_samples: at most this many samples (drawn at random) per E-step
    :param starved_share: a component whose prior falls below ``starved_share / K`` is re-seeded by splitting the
        busiest one (0: never)
    :param seed: seed of the minibatch order
    """

    def __init__(self, latent_model: LatentModel, learning_rate: float = 1e-3, n_epochs: int = 2, batch_size: int = 1024,
                 window: int = 2, estimator: str = "enumerate", temperature: float = 1.0, min_temperature: float = 0.1,
                 anneal_rate: float = 0.05, team_pooling: bool = False, max_samples: int = 2048,
                 starved_share: float = 0.1, seed: int = 0) -> None:
        if estimator not in ("enumerate", "gumbel"):
            raise ValueError(f"estimator must be 'enumerate' or 'gumbel', got {estimator!r}")
        for name, value in (("n_epochs", n_epochs), ("batch_size", batch_size), ("window", window),
                            ("max_samples", max_samples)):
            if value < 1:
                raise ValueError(f"{name} must be >= 1, got {value}")
        if not temperature > 0 or not 0 < min_temperature <= temperature:
            raise ValueError(f"need 0 < min_temperature <= temperature, got {min_temperature} and {temperature}")
        self.model = latent_model
        self.optimizer = th.optim.Adam([p for p in latent_model.parameters() if p.requires_grad], lr=learning_rate)
        self.n_epochs, self.batch_size, self.max_samples = n_epochs, batch_size, max_samples
        self.memory: deque[LatentBatch] = deque(maxlen=window)
        self.estimator = estimator
        self.initial_temperature, self.min_temperature, self.anneal_rate = temperature, min_temperature, anneal_rate
        self.team_pooling = team_pooling
        self.starved_share = starved_share
        self.n_updates = 0
        self.generator = th.Generator().manual_seed(seed)

    @property
    def temperature(self) -> float:
        return max(self.min_temperature, self.initial_temperature * math.exp(-self.anneal_rate * self.n_updates))

    def add(self, batch: LatentBatch) -> None:
        """Remember one E-step's data (the oldest leaves once ``window`` data sets are kept)."""
        if len(batch):
            self.memory.append(batch)

    def _shuffle(self, data: LatentBatch) -> tuple[th.Tensor, th.Tensor]:
        """A random order of the samples and where each unit starts in it.

        A unit is one sample, or with team pooling one group (the agents of one copy and step), which stays
        whole in subsampling and in minibatches so that its members' evidence is pooled together.
        """
        units = th.unique(data.groups, return_inverse=True)[1] if self.team_pooling else th.arange(len(data))
        rank = th.randperm(int(units.max()) + 1, generator=self.generator)[units]
        order = th.argsort(rank, stable=True)
        ranked = rank[order]
        starts = th.cat([th.zeros(1, dtype=th.long), th.nonzero(ranked[1:] != ranked[:-1]).flatten() + 1])
        return order, starts

    def _data(self) -> LatentBatch:
        """The kept rollouts, at most ``max_samples`` of them (whole units, drawn at random)."""
        data = LatentBatch.cat(list(self.memory))
        if len(data) > self.max_samples:
            order, starts = self._shuffle(data)
            ends = th.cat([starts[1:], th.tensor([len(data)])])
            fitting = ends[ends <= self.max_samples]
            cut = int(fitting[-1]) if len(fitting) else int(ends[0])  # whole units; at least one
            data = LatentBatch(*(getattr(data, name)[order[:cut]] for name in FIELDS))
        return data

    def _minibatches(self, data: LatentBatch) -> list[th.Tensor]:
        """Random minibatches of about ``batch_size`` samples, cut between units."""
        order, starts = self._shuffle(data)
        targets = th.tensor(list(range(self.batch_size, len(data), self.batch_size)), dtype=th.long)
        ends = th.cat([starts, th.tensor([len(data)])])[th.searchsorted(starts, targets)].unique().tolist()
        cuts = [0, *[c for c in ends if 0 < c < len(data)], len(data)]
        return [order[a:b] for a, b in pairwise(cuts)]

    def step(self, train: bool = True) -> dict[str, float]:
        """One E-step on the kept data; ``train=False`` (E-step frozen) changes nothing and only reports.

        Each minibatch: the decoder's stretch log-likelihood ``L`` ``(B, K)`` once; the exact responsibilities
        ``r ∝ pi exp(L)`` (no gradient); the decoder maximises ``E_r[L]`` (exact, or one Gumbel-softmax sample)
        and the encoder fits ``q_phi(z | h_t)`` to ``r`` by cross-entropy. The statistics and the new prior
        ``pi`` (the mean responsibilities) come from the last epoch's minibatches, each taken before its update.

        :return: statistics for the logger: the ELBO under the encoder's posterior and its reconstruction and KL
            terms, the prior's and the posterior's entropy, the temperature
        """
        if not self.memory:
            return {}
        data = self._data()
        n_epochs = self.n_epochs if train else 1
        self.model.train(train)
        totals: dict[str, th.Tensor] = {}
        for epoch in range(n_epochs):
            last = epoch == n_epochs - 1
            for idx in self._minibatches(data):
                window, next_slot = data.window[idx], data.next_slot[idx]
                groups = data.groups[idx] if self.team_pooling else None
                with th.set_grad_enabled(train):
                    log_lik = self.model.stretch_log_likelihood(window, next_slot)
                    # E: responsibilities of the components for each stretch, from the current decoder and prior.
                    responsibilities = self.model.responsibilities_from(log_lik, groups).exp()
                    # Decoder: maximise the expected log-likelihood under them (exact, or one Gumbel-softmax sample).
                    recon = self.model.expected_log_likelihood(window, next_slot, responsibilities, self.estimator,
                                                               self.temperature, log_likelihood=log_lik)
                    # Encoder: q_phi(z | h_t) learns to predict them from the history alone (the ELBO's optimal q).
                    log_q = self.model.posterior_logits(window)
                    if groups is not None:
                        log_q = self.model.pool(log_q, groups)
                    loss = -recon.mean() - (responsibilities * log_q).sum(-1).mean()
                if last:
                    with th.no_grad():
                        terms = self.model.elbo(window, next_slot, log_likelihood=log_lik.detach(), log_q=log_q.detach())
                    self._accumulate(totals, terms, responsibilities)
                if train:
                    self.optimizer.zero_grad()
                    loss.backward()
                    th.nn.utils.clip_grad_norm_(self.model.parameters(), 10.0)
                    self.optimizer.step()
        self.model.train(False)
        revived = 0
        if train:
            self.n_updates += 1
            self.model.set_prior(totals["responsibilities"][None] / len(data))  # pi in closed form
            revived = self._revive_starved_components()
        prior = self.model.prior()
        stats = {key: float(totals[key] / len(data)) for key in ("elbo", "recon", "kl", "posterior_entropy")}
        return {
            **stats,
            "prior_entropy": float(-(prior * prior.log()).sum()),
            "temperature": self.temperature,
            "n_samples": float(len(data)),
            "revived_components": float(revived),
        }

    @staticmethod
    def _accumulate(totals: dict[str, th.Tensor], terms: dict[str, th.Tensor], responsibilities: th.Tensor) -> None:
        """Add a minibatch's ELBO terms (enumerated, under the encoder's posterior) and responsibilities to ``totals``."""
        log_q = terms["log_q"]
        for key, value in (("elbo", terms["elbo"].sum()), ("recon", terms["recon"].sum()), ("kl", terms["kl"].sum()),
                           ("posterior_entropy", -(log_q.exp() * log_q).sum()),
                           ("responsibilities", responsibilities.sum(0))):
            totals[key] = totals.get(key, 0) + value

    def _revive_starved_components(self) -> int:
        """Split the busiest component into every component whose prior fell below ``starved_share / K``."""
        prior = self.model.prior()
        starved = th.nonzero(prior < self.starved_share / self.model.n_components).flatten().tolist()
        for dead in starved:
            self.model.split_component(dead, int(self.model.prior().argmax()), generator=self.generator)
        return len(starved)


class EMCallback(BaseCallback):
    """Run the E-step after each rollout and log ``latent/*`` scalars.

    The algorithm supplies the data through ``latent_batch()`` and owns ``e_step`` (an :class:`EStep`),
    ``freeze_e_step`` and ``e_step_interval`` (rollouts between E-steps). After each collection step it
    calls the algorithm's ``record_collection_step()`` (EM-PPO keeps the posteriors its actions were drawn with).
    """

    def __init__(self, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.rollouts = 0

    def _on_rollout_start(self) -> None:
        self.model.start_collection()

    def _on_step(self) -> bool:
        self.model.record_collection_step()
        return True

    def _on_rollout_end(self) -> None:
        model = self.model
        self.rollouts += 1
        if self.rollouts % model.e_step_interval:
            return
        model.e_step.add(model.latent_batch())
        stats = model.e_step.step(train=not model.freeze_e_step)
        for key, value in stats.items():
            self.logger.record(f"latent/{key}", value)
