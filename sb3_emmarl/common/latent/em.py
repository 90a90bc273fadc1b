"""The E-step (Algorithm 2, line 11): EM for a mixture of transition models with one ``z`` per episode.

Its data are transitions ``(x_t, a_t) -> x_{t+1}`` tagged with the episode they belong to
(:class:`Transitions`; the algorithms build them from their rollout or replay buffer). Episodes are
stitched across rollouts: the E-step keeps the last ``window`` rollouts' transitions, so an episode that
began in an earlier rollout still counts as one. Each epoch of an E-step:

1. **E**: the responsibilities of the components for every episode from all its evidence,
   ``r_k ∝ pi_k exp(beta * sum_t log p(x_{t+1} | x_t, a_t, z = k))`` (exact: ``z`` is categorical);
2. **fit**: gradient steps on minibatches of transitions (at most ``max_transitions`` of them, drawn at
   random) maximising ``E_r[log p(x_{t+1} | x_t, a_t, z)]``,
   each transition weighted by its episode's responsibilities (``"enumerate"``, exact), or with one
   Gumbel-softmax sample of ``z`` per transition drawn from them (``"gumbel"``, the paper's estimator);

then ``pi`` is set in closed form to the mean responsibilities over episodes, and a component whose share
fell below ``starved_share / K`` is re-seeded by splitting the busiest one. With ``r`` the exact posterior,
the ELBO equals the marginal log-likelihood ``sum_episodes log sum_k pi_k exp(L_k)``: that is what
:meth:`EStep.step` reports as ``log_likelihood`` (per transition).

When the environment's plug-in counts readings (on the reserve), the responsibilities also read each episode's counts
(:class:`EpisodeCounts`, the count model of :mod:`~sb3_emmarl.common.latent.counts`), weighed by the plug-in's
``weight`` (``count_weight``) as in the beliefs, and each E-step fits the count model's rates by batch EM over every
episode it remembers (:meth:`EStep._remember_counts`: each episode's counts and exposures summed over all its rollouts,
the newest :data:`COUNT_TABLE_EPISODES` episodes, each weighted by :data:`COUNT_DECAY` per E-step since its last
reading, as the policy and so the data drift), :data:`COUNT_ITERATIONS` rounds from the current rates: responsibilities
of every remembered episode (its count evidence, plus its transition evidence while it is kept), then ``rates =
(weighted sums of counts + a * pooled rate) / (weighted sums of exposures + a)``. Decaying running sums that each
rollout's episodes joined once, weighted by the responsibilities of that moment, would keep the random start's
assignments in the rates (0.99 ** 12 = 0.89 of their weight after the 12 E-steps of a 500k-step run); re-assigning
every remembered episode at every E-step instead lets the rates follow the current assignments (what it changes:
docs/lab/results-history.md). The first round of the first E-step weighs the episodes by random
responsibilities (Dirichlet(1), from the E-step's generator): equal starting rates would give every component the same
share of every episode, and the components' rates would never part (EM's usual random start; annealing instead did
worse online: 0.55 against 0.64 in the measurement that the reserve's ``COUNT_EVIDENCE_WEIGHT`` cites).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
import torch.nn.functional as F

from sb3_emmarl.common.latent.counts import check_factors, check_rings, count_rates
from sb3_emmarl.common.latent.diagnostics import assignment_agreement
from sb3_emmarl.common.latent.model import LOG_STD_BOUNDS, LatentModel, StepLikelihood, sum_by_group
from sb3_emmarl.common.latent.parts import PartsMemory

if TYPE_CHECKING:
    from sb3_emmarl.common.latent.evidence import CountEvidence

FIELDS = ("features", "actions", "next_features", "episodes")
#: Decay per E-step of the count model's running sums.
COUNT_DECAY = 0.99
#: Rounds of responsibilities and rates of the count model per E-step (on the episodes' summed counts: cheap).
COUNT_ITERATIONS = 5
#: Episodes the count model remembers (the newest; at ``COUNT_DECAY`` an episode 460 E-steps old weighs 0.01).
COUNT_TABLE_EPISODES = 4096
#: The per-episode fields of :attr:`EStep.count_table`.
ROW_FIELDS = ("ids", "counts", "exposure", "age")
#: Transitions per chunk when the responsibilities read every kept transition: the per-feature densities of all of
#: them at once (transitions x K x features floats) would briefly hold hundreds of MB at the zoo's E-step window.
LIKELIHOOD_CHUNK = 8192


@dataclass
class Transitions:
    """E-step data: ``features`` ``x_t`` ``(N, d_x)``, encoded ``actions`` ``a_t`` ``(N, d_a)``,
    ``next_features`` ``x_{t+1}`` ``(N, d_x)`` and ``episodes`` ``(N,)`` (int ids; with team pooling, the
    agents of one environment copy share their episode's id)."""

    features: th.Tensor
    actions: th.Tensor
    next_features: th.Tensor
    episodes: th.Tensor

    def __len__(self) -> int:
        return len(self.features)

    @staticmethod
    def from_numpy(features: np.ndarray, actions: np.ndarray, next_features: np.ndarray, episodes: np.ndarray,
                   device: th.device | str = "cpu") -> Transitions:
        def tensor(x: np.ndarray) -> th.Tensor:
            return th.as_tensor(np.ascontiguousarray(x), dtype=th.float32, device=device)

        return Transitions(tensor(features), tensor(actions), tensor(next_features),
                           th.as_tensor(np.asarray(episodes), dtype=th.long, device=device))


@dataclass
class EpisodeCounts:
    """Reading counts of one rollout, summed per episode: ``episodes`` ``(S,)`` ids (as in :class:`Transitions`),
    ``counts`` ``(S, channels * bins)`` and ``exposure`` ``(S, bins)``."""

    episodes: th.Tensor
    counts: th.Tensor
    exposure: th.Tensor

    @staticmethod
    def from_steps(episodes: np.ndarray, counts: np.ndarray, exposure: np.ndarray,
                   device: th.device | str = "cpu") -> EpisodeCounts:
        """Sum per-step ``counts`` ``(N, channels, bins)`` and ``exposure`` ``(N, bins)`` by their steps' ``episodes``."""
        ids, inverse = np.unique(np.asarray(episodes, dtype=np.int64), return_inverse=True)
        index = th.as_tensor(inverse)

        def summed(values: np.ndarray) -> th.Tensor:
            rows = th.as_tensor(values.reshape(len(values), -1), dtype=th.float32)
            return th.zeros(len(ids), rows.shape[1]).index_add_(0, index, rows).to(device)

        return EpisodeCounts(th.as_tensor(ids, device=device), summed(counts), summed(exposure))

    @staticmethod
    def from_observations(counter: CountEvidence, observations: np.ndarray | Sequence[np.ndarray],
                          episodes: np.ndarray, device: th.device | str = "cpu") -> EpisodeCounts:
        """The reading counts of ``observations`` summed by their ``episodes``.

        :param counter: the environment's count evidence (its plug-in's)
        :param observations: ``(N, d)`` flat observations (``d >= obs_dim``: augmented ones are read in place), or
            blocks ``(..., d)`` that stack to them row by row (a rollout's observations and the last ones, without
            the copy that stacking them would make)
        :param episodes: ``(N,)`` episode ids (>= 0), or -1 for a row to skip
        """
        episodes = np.asarray(episodes, dtype=np.int64).reshape(-1)
        kept = episodes >= 0
        ids, index = np.unique(episodes[kept], return_inverse=True)
        groups = np.full(len(episodes), -1, dtype=np.int64)
        groups[kept] = index
        blocks = [observations] if isinstance(observations, np.ndarray) else list(observations)
        if not blocks:
            raise ValueError("observations must be an array or at least one block of rows")
        summed: np.ndarray | None = None
        start = 0
        for block in blocks:
            rows = block.reshape(-1, block.shape[-1])
            summed = counter.grouped(rows, groups[start:start + len(rows)], len(ids), out=summed)
            start += len(rows)
        if start != len(episodes):
            raise ValueError(f"episodes must have one entry per observation ({start}), got {len(episodes)}")
        assert summed is not None  # (at least one block)
        return EpisodeCounts(th.as_tensor(ids, device=device),
                             th.as_tensor(summed[:, 1:].reshape(len(ids), -1), dtype=th.float32, device=device),
                             th.as_tensor(summed[:, 0], dtype=th.float32, device=device))


def _copy(tensor: th.Tensor) -> th.Tensor:
    """A CPU copy of ``tensor`` (a view of the E-step's memory would carry its whole block into a checkpoint)."""
    return tensor.detach().to("cpu", copy=True)


def transition_log_likelihoods(model: LatentModel, data: Transitions, temperature: float = 1.0) -> th.Tensor:
    """``log p(x_{t+1} | x_t, a_t, z = k)`` of every transition of ``data`` ``(N, K)``, tempered as the beliefs temper
    it (``temperature`` on the transition features' terms, the readings' untempered:
    :meth:`~sb3_emmarl.common.latent.model.StepLikelihood.log_likelihood`), without gradient, in chunks of
    :data:`LIKELIHOOD_CHUNK` transitions: through :class:`~sb3_emmarl.common.latent.model.StepLikelihood`, whose
    compiled density never builds the ``(N, K, d_x)`` arrays that
    :meth:`~sb3_emmarl.common.latent.model.LatentModel.transition_log_likelihood` needs for its gradient (a third of
    an E-step's time went into them)."""
    likelihood = StepLikelihood(model)
    readings = model.transition_mask is not None  # (without readings, tempered in float32 as it always was)
    arrays = [part.detach().cpu().numpy() for part in (data.features, data.actions, data.next_features)]
    features, actions, next_features = arrays
    chunks = [likelihood.log_likelihood(features[i:i + LIKELIHOOD_CHUNK], actions[i:i + LIKELIHOOD_CHUNK],
                                        next_features[i:i + LIKELIHOOD_CHUNK], temperature if readings else 1.0)
              for i in range(0, len(data), LIKELIHOOD_CHUNK)]
    values = np.concatenate(chunks) if chunks else np.zeros((0, model.n_components))
    tensor = th.as_tensor(values, dtype=th.float32, device=data.features.device)
    return tensor if readings else temperature * tensor


def episode_ids(counters: np.ndarray, new_episode: np.ndarray, agents_per_copy: int = 1,
                team_pooling: bool = False) -> np.ndarray:
    """Episode ids of ``(T, n)`` steps of ``n`` vector entries, continuing the entries' ``counters`` (updated in place).

    :param counters: episodes begun so far per entry ``(n,)``
    :param new_episode: ``(T, n)`` True where a step is the first of a new episode
    :param agents_per_copy: agents per environment copy
    :param team_pooling: the agents of one copy share their episode ids (they reset together)
    :return: ``(T, n)`` int ids, distinct across entries (or copies) and episodes
    """
    n = new_episode.shape[1]
    counts = counters[None] + np.cumsum(new_episode, axis=0, dtype=np.int64)
    counters[:] = counts[-1] if len(counts) else counters
    if team_pooling:
        units, n_units = np.arange(n) // max(1, agents_per_copy), -(-n // max(1, agents_per_copy))
    else:
        units, n_units = np.arange(n), n
    return counts * n_units + units


class EStep:
    """Fit the mixture of transition models to recent episodes by EM; set ``pi`` in closed form.

    :param latent_model: the latent model (its prior is updated in place)
    :param learning_rate: Adam learning rate of the decoder
    :param n_epochs: EM iterations per E-step (responsibilities, then a pass of gradient steps)
    :param batch_size: transitions per gradient step
    :param window: rollouts of transitions kept (every rollout is added, E-step or not); the responsibilities
        read all of them
    :param max_transitions: transitions of each EM iteration's gradient pass, drawn at random from the kept ones
        (all of them when fewer)
    :param estimator: ``"enumerate"`` or ``"gumbel"``
    :param temperature: initial Gumbel-softmax temperature
    :param min_temperature: floor of the annealed temperature
    :param anneal_rate: the temperature is ``max(min_temperature, temperature * exp(-anneal_rate * n_updates))``
    :param likelihood_temperature: ``beta`` on the log-likelihoods in the responsibilities (as in the beliefs)
    :param starved_share: a component whose prior falls below ``starved_share / K`` is re-seeded (0: never)
    :param starved_patience: ... once its prior has been below it at this many E-steps in a row (1: at the first; a
        prior that dips below it for fewer E-steps, as one fitted to few episodes of equally likely modes does, is
        left alone)
    :param seed: seed of the minibatch order and of the re-seeding noise
    :param count_factors: ``(F1, F2)`` with ``F1 * F2 = K``: the count model's rates factor as where x how far
        (:func:`~sb3_emmarl.common.latent.counts.factored_rates`); None: every component's every bin its own
    :param count_rings: rings per block of the count model's bins (with ``count_factors``; the plug-in's ``n_rings``)
    :param count_weight: the factor on the count log-likelihood in the responsibilities (the plug-in's ``weight``)
    """

    def __init__(self, latent_model: LatentModel, *, learning_rate: float = 1e-3, n_epochs: int = 5,
                 batch_size: int = 256, window: int = 2, max_transitions: int = 16384, estimator: str = "enumerate",
                 temperature: float = 1.0, min_temperature: float = 0.1, anneal_rate: float = 0.05,
                 likelihood_temperature: float = 1.0, starved_share: float = 0.1, starved_patience: int = 1,
                 seed: int = 0,
                 count_factors: tuple[int, int] | None = None, count_rings: int = 1, count_weight: float = 1.0) -> None:
        if estimator not in ("enumerate", "gumbel"):
            raise ValueError(f"estimator must be 'enumerate' or 'gumbel', got {estimator!r}")
        for name, value in (("n_epochs", n_epochs), ("batch_size", batch_size), ("window", window),
                            ("max_transitions", max_transitions), ("starved_patience", starved_patience)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}")
        if not temperature > 0 or not 0 < min_temperature <= temperature:
            raise ValueError(f"need 0 < min_temperature <= temperature, got {min_temperature} and {temperature}")
        if not learning_rate > 0 or not likelihood_temperature > 0 or not 0 <= starved_share < 1:
            raise ValueError(f"need learning_rate > 0, likelihood_temperature > 0 and 0 <= starved_share < 1, got "
                             f"{learning_rate}, {likelihood_temperature} and {starved_share}")
        self.count_factors = check_factors(count_factors, latent_model.n_components)
        self.count_rings = check_rings(count_rings, latent_model.count_log_rates.shape[-1]
                                       if latent_model.count_log_rates is not None else 1, "count_rings")
        if isinstance(count_weight, bool) or not (isinstance(count_weight, (int, float)) and 0 < count_weight < math.inf):
            raise ValueError(f"count_weight must be a finite number > 0, got {count_weight!r}")
        self.count_weight = count_weight
        self.model = latent_model
        self.optimizer = th.optim.Adam(latent_model.parameters(), lr=learning_rate)
        latent_model.watch(self.optimizer)  # (its steps write the model: the beliefs' copy follows)
        self.n_epochs, self.batch_size, self.max_transitions = int(n_epochs), int(batch_size), int(max_transitions)
        # The kept rollouts' transitions and reading counts, back to back in a few large tensors (see parts.py).
        self.memory: PartsMemory[Transitions] = PartsMemory(Transitions, int(window))
        self.count_memory: PartsMemory[EpisodeCounts] = PartsMemory(EpisodeCounts, int(window))  # beside each
        self.fresh = 0  # rollouts added since the last E-step
        #: the count model's memory of every episode (:meth:`_remember_counts`): sorted ``ids``, their summed ``counts``
        #: and ``exposure``, ``age`` (E-steps since their last reading) and the ``pooled`` readings and exposure
        self.count_table: dict[str, th.Tensor] = {}
        self.estimator = estimator
        self.initial_temperature, self.min_temperature, self.anneal_rate = temperature, min_temperature, anneal_rate
        self.likelihood_temperature = float(likelihood_temperature)
        self.starved_share, self.starved_patience = starved_share, int(starved_patience)
        #: E-steps in a row at which each component's prior was below ``starved_share / K``
        self.starved_steps = th.zeros(latent_model.n_components, dtype=th.long)
        self.n_updates = 0
        self.generator = th.Generator().manual_seed(seed)

    def state_dict(self) -> dict[str, Any]:
        """Everything the next E-steps depend on besides the model's weights: the optimizer, the update counter (it
        drives the Gumbel temperature), the random generator and the kept transitions (on the CPU). Named as torch's
        ``state_dict``, so that SB3's ``save`` writes it with ``torch.save`` beside the policy's weights."""
        return {"optimizer": self.optimizer.state_dict(), "n_updates": self.n_updates,
                "generator": self.generator.get_state(),
                "memory": [{name: _copy(getattr(part, name)) for name in FIELDS} for part in self.memory],
                "count_memory": [None if part is None else [_copy(part.episodes), _copy(part.counts),
                                                            _copy(part.exposure)] for part in self.count_memory],
                "fresh": self.fresh, "count_table": {name: value.cpu() for name, value in self.count_table.items()},
                "starved_steps": self.starved_steps.clone()}

    def load_state_dict(self, state: dict[str, Any], strict: bool = True) -> None:
        """Restore a :meth:`state_dict` (the E-step then continues as if it had not stopped).

        :param strict: accepted for SB3's ``set_parameters``, which passes it to every saved object; the state is
            always restored whole
        """
        self.optimizer.load_state_dict(state["optimizer"])
        self.n_updates = int(state["n_updates"])
        self.generator.set_state(state["generator"])
        device = next(self.model.parameters()).device
        self.memory.clear()
        for part in state["memory"]:
            self.memory.append(Transitions(*(part[name].to(device) for name in FIELDS)))
        self.count_memory.clear()
        for part in state.get("count_memory", [None] * len(self.memory)):
            self.count_memory.append(None if part is None else EpisodeCounts(*(x.to(device) for x in part)))
        self.fresh = int(state.get("fresh", 0))
        # (a state saved before 0.22 has no count of starved E-steps: every component starts at 0)
        self.starved_steps = state.get("starved_steps", th.zeros(self.model.n_components, dtype=th.long)).clone()
        # (a state saved before 0.14.0 holds running sums, "count_sums", instead: the table then starts empty)
        self.count_table = {name: value.to(device) for name, value in state.get("count_table", {}).items()}

    @property
    def temperature(self) -> float:
        """The Gumbel-softmax temperature of the next E-step."""
        return max(self.min_temperature, self.initial_temperature * math.exp(-self.anneal_rate * self.n_updates))

    def add(self, transitions: Transitions, counts: EpisodeCounts | None = None) -> None:
        """Remember one rollout's transitions, and its episodes' reading counts if the model has a count model (the
        oldest rollout leaves once ``window`` are kept)."""
        if len(transitions):
            self.memory.append(transitions)
            self.count_memory.append(counts if self.model.has_counts else None)
            self.fresh = min(self.fresh + 1, self.memory.maxlen or 1)

    def _episode_counts(self, ids: th.Tensor, parts: list[EpisodeCounts | None]) -> tuple[th.Tensor, th.Tensor,
                                                                                          list[tuple]]:
        """The reading counts ``(S, channels * bins)`` and exposures ``(S, bins)`` of the sorted episode ``ids``
        summed over ``parts``, and for each part ``(part, index of its rows into ids, whether ids holds them)``."""
        log_rates = self.model.count_log_rates
        assert log_rates is not None  # (a model with the count term)
        counts = th.zeros(len(ids), log_rates[0].numel(), device=ids.device)
        exposure = th.zeros(len(ids), log_rates.shape[2], device=ids.device)
        rows = self._rows(ids, parts)
        for part, index, known in rows:
            counts.index_add_(0, index[known], part.counts[known])
            exposure.index_add_(0, index[known], part.exposure[known])
        return counts, exposure, rows

    @staticmethod
    def _rows(ids: th.Tensor, parts: list[EpisodeCounts | None]) -> list[tuple]:
        """For each part with episodes: ``(part, index of its rows into the sorted ids, whether ids holds them)``."""
        rows = []
        for part in parts:
            if part is None or not len(part.episodes):
                continue
            index = th.searchsorted(ids, part.episodes).clamp_max(len(ids) - 1)
            rows.append((part, index, ids[index] == part.episodes))  # an episode without kept transitions: no row
        return rows

    def _data(self) -> Transitions:
        """Every kept transition, oldest first (a view of the memory's blocks)."""
        data = self.memory.contiguous()
        assert data is not None  # (the E-step runs on a memory with transitions)
        return data

    def responsibilities(self, data: Transitions) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """Log-responsibilities of each episode ``(S, K)``, each transition's episode index ``(N,)`` and each
        episode's summed tempered log-likelihoods ``(S, K)`` (no gradient)."""
        with th.no_grad():
            log_lik = transition_log_likelihoods(self.model, data, self.likelihood_temperature)
            evidence, index = sum_by_group(log_lik, data.episodes)
            if self.model.has_counts and any(part is not None for part in self.count_memory):
                counts, exposure, _ = self._episode_counts(th.unique(data.episodes), list(self.count_memory))
                count_evidence = self.model.count_log_likelihood(counts, exposure)
                evidence = evidence + self.count_weight * count_evidence
            return self.model.posterior_from(evidence), index, evidence

    def _remember_counts(self, ids: th.Tensor) -> None:
        """Add the fresh rollouts' reading counts to :attr:`count_table` (an episode's parts add up in its one row),
        age every row by one E-step (rows with fresh readings start again at 0) and keep the newest
        :data:`COUNT_TABLE_EPISODES` episodes.

        :param ids: the sorted episode ids of the kept transitions
        """
        log_rates = self.model.count_log_rates
        assert log_rates is not None  # (a model with the count term)
        _, channels, bins = log_rates.shape
        device = ids.device
        table = self.count_table or {"ids": th.zeros(0, dtype=th.long, device=device),
                                     "counts": th.zeros(0, channels * bins, dtype=th.float64, device=device),
                                     "exposure": th.zeros(0, bins, dtype=th.float64, device=device),
                                     "age": th.zeros(0, dtype=th.float64, device=device),
                                     "pooled": th.zeros(channels + 1, dtype=th.float64, device=device)}
        table["age"] = table["age"] + 1
        for part, _, known in self._rows(ids, list(self.count_memory)[len(self.count_memory) - self.fresh:]):
            episodes, counts, exposure = part.episodes[known], part.counts[known].double(), part.exposure[known].double()
            table["pooled"][:channels] += counts.reshape(-1, channels, bins).sum((0, 2))  # every reading once
            table["pooled"][channels] += exposure.sum()
            new = th.unique(episodes[~th.isin(episodes, table["ids"])])
            if len(new):  # new rows, then sorted again: the entries' ids interleave (team pooling's units)
                table["ids"] = th.cat([table["ids"], new])
                table["counts"] = th.cat([table["counts"], counts.new_zeros(len(new), counts.shape[1])])
                table["exposure"] = th.cat([table["exposure"], exposure.new_zeros(len(new), bins)])
                table["age"] = th.cat([table["age"], table["age"].new_zeros(len(new))])
                order = th.argsort(table["ids"])
                for name in ROW_FIELDS:
                    table[name] = table[name][order]
            row = th.searchsorted(table["ids"], episodes)
            table["counts"].index_add_(0, row, counts)
            table["exposure"].index_add_(0, row, exposure)
            table["age"][row] = 0.0
        for name in ROW_FIELDS:  # the lowest ids leave: each entry's ids grow with time, so these are the oldest
            table[name] = table[name][-COUNT_TABLE_EPISODES:]
        self.count_table = table

    def _fit_counts(self, data: Transitions, evidence: th.Tensor) -> None:
        """The count model's rates by batch EM over :attr:`count_table` (every episode remembered, weighted by
        ``COUNT_DECAY ** age``), :data:`COUNT_ITERATIONS` rounds from the current rates; see the module's text.

        :param data: the kept transitions
        :param evidence: each kept episode's tempered evidence ``(S, K)`` as :meth:`responsibilities` gave it
        """
        ids = th.unique(data.episodes)
        assert self.model.count_log_rates is not None  # (a model with the count term)
        k, channels, bins = self.model.count_log_rates.shape
        start = not self.count_table
        self._remember_counts(ids)
        table = self.count_table
        weight = (COUNT_DECAY ** table["age"])[:, None]
        pooled = (table["pooled"][:channels] / table["pooled"][channels].clamp_min(1e-12)).cpu().numpy()

        def count_evidence(counts: th.Tensor, exposure: th.Tensor) -> th.Tensor:
            with th.no_grad():
                return self.count_weight * self.model.count_log_likelihood(counts.float(), exposure.float()).double()

        # What the transitions say of the kept episodes (their evidence without its count part); 0 for the others.
        window_counts, window_exposure, _ = self._episode_counts(ids, list(self.count_memory))
        other = th.zeros(len(table["ids"]), k, dtype=th.float64, device=ids.device)
        position = th.searchsorted(table["ids"], ids).clamp_max(max(len(table["ids"]) - 1, 0))
        inside = table["ids"][position] == ids
        other[position[inside]] = (evidence.double() - count_evidence(window_counts, window_exposure))[inside]
        for iteration in range(COUNT_ITERATIONS):
            if start and iteration == 0:  # EM's random start
                r = -th.rand(len(table["ids"]), k, generator=self.generator, dtype=th.float64).log()
                r = (r / r.sum(1, keepdim=True)).to(ids.device)
            else:
                r = th.softmax(other + count_evidence(table["counts"], table["exposure"])
                               + self.model.log_prior.double(), dim=1)
            weighted = r * weight
            rates = count_rates((weighted.T @ table["counts"]).reshape(k, channels, bins).cpu().numpy(),
                                (weighted.T @ table["exposure"]).cpu().numpy(), pooled, self.count_factors,
                                self.count_rings)
            self.model.set_count_rates(th.as_tensor(rates, dtype=th.float32, device=ids.device))

    def step(self, train: bool = True) -> dict[str, float]:
        """One E-step on the kept transitions; ``train=False`` (E-step frozen) changes nothing and only reports.

        :return: statistics for the logger: marginal log-likelihood per transition, mean entropy of the
            responsibilities and of the prior, transitions and episodes used, temperature, re-seeded components, and
            how many episodes keep their component from the E-step's first responsibilities to its last ones, as
            they are and after the best relabelling (``assignment_kept``, ``assignment_matched``; see
            :func:`~sb3_emmarl.common.latent.diagnostics.assignment_agreement`)
        """
        if not self.memory:
            return {}
        data = self._data()
        if train and self.n_updates == 0:  # start the deviations at the data's scale, not at 1
            with th.no_grad():
                change = (data.next_features - data.features).std(dim=0) + 1e-3
                self.model.decoder_log_std.copy_(change.log().clamp(*LOG_STD_BOUNDS))
            self.model.mark_changed()
        self.model.train(train)
        log_r, index, evidence = self.responsibilities(data)
        first_assignment = log_r.argmax(-1)
        for epoch in range(self.n_epochs if train else 0):
            if epoch:
                log_r, index, evidence = self.responsibilities(data)
            order = th.randperm(len(data), generator=self.generator)[: self.max_transitions]
            for start in range(0, len(order), self.batch_size):
                idx = order[start:start + self.batch_size]
                log_lik = self.model.transition_log_likelihood(data.features[idx], data.actions[idx],
                                                               data.next_features[idx])
                weights = log_r[index[idx]]
                if self.estimator == "enumerate":
                    recon = (weights.exp() * log_lik).sum(-1)
                else:
                    z = F.gumbel_softmax(weights, tau=self.temperature, hard=False)
                    recon = self.model.mixed_log_likelihood(data.features[idx], data.actions[idx],
                                                            data.next_features[idx], z)
                self.optimizer.zero_grad()
                (-recon.mean()).backward()
                th.nn.utils.clip_grad_norm_(self.model.parameters(), 10.0)
                self.optimizer.step()
        # No gradient may outlive the E-step: the policy's optimizer excludes the latent model, so its zero_grad
        # would leave them, and the M-step's gradient clipping (over all the policy's parameters) would count them.
        self.optimizer.zero_grad(set_to_none=True)
        self.model.train(False)
        # The statistics and the prior come from the last iteration's responsibilities, taken before its gradient
        # pass (as SB3 logs losses): one pass over the data fewer.
        marginal = th.logsumexp(evidence + self.model.log_prior, dim=-1).sum() / self.likelihood_temperature
        revived = 0
        if train:
            if self.model.has_counts and self.fresh and any(part is not None for part in self.count_memory):
                self._fit_counts(data, evidence)
            self.fresh = 0
            self.n_updates += 1
            self.model.set_prior(log_r.exp())  # pi in closed form
            revived = self._revive_starved_components()
        prior = self.model.prior()
        kept, matched = assignment_agreement(first_assignment.cpu().numpy(), log_r.argmax(-1).cpu().numpy(),
                                             self.model.n_components)
        return {
            "log_likelihood": float(marginal / len(data)),
            "posterior_entropy": float(-(log_r.exp() * log_r).sum(-1).mean()),
            "prior_entropy": float(-(prior * prior.log()).sum()),
            "temperature": self.temperature,
            "n_transitions": float(len(data)),
            "n_episodes": float(len(log_r)),
            "revived_components": float(revived),
            "assignment_kept": kept,
            "assignment_matched": matched,
        }

    def _revive_starved_components(self) -> int:
        """Split the busiest component into every component whose prior has been below ``starved_share / K`` at
        ``starved_patience`` E-steps in a row."""
        prior = self.model.prior()
        below = (prior < self.starved_share / self.model.n_components).cpu()
        self.starved_steps = th.where(below, self.starved_steps + 1, th.zeros_like(self.starved_steps))
        starved = th.nonzero(self.starved_steps >= self.starved_patience).flatten().tolist()
        for dead in starved:
            self.model.split_component(dead, int(self.model.prior().argmax()), generator=self.generator)
            self.starved_steps[dead] = 0
        return len(starved)
