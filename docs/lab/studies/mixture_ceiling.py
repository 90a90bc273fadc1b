"""How well can EM-PPO's latent model tell the reserve's hidden mode? Fitted by EM, and fitted told the mode.

EM-PPO's belief is the exact posterior of ``z`` under its mixture of transition models
``p(x_{t+1} | x_t, a_t, z)`` (see docs/em.md), so it can tell the mode only as well as that model, fitted by
the E-step, separates the modes. This script separates the two questions, on the default reserve with
uniformly random actions (no policy, so nothing but the model is measured):

- **em**: the latent model and E-step of ``EMPPO`` built from the zoo's ``em_ppo.yml`` (its ``K``, ``beta``,
  decoder, E-step epochs, batch and transitions per pass; team pooling), fitted unsupervised by
  ``--e-steps`` E-steps over all the training episodes, as EM-PPO fits it over its recent rollouts;
- **told**: the same model and E-step with each training episode's responsibilities fixed to its true mode
  (component ``k`` is mode ``k``): what this model family and these features can do at best, whatever EM
  finds. It is the ceiling of the first row.

Beside it, the same two fittings of a model that can say *where* readings are made: the mixture of Poisson models
of reading counts by (map block, window ring) of :mod:`sb3_emmarl.common.latent.counts` (``counts``), fitted
by its annealed EM, or told, on the team totals of the same training episodes (``transitions`` is EM-PPO's
model), and the same count model with its rates factored as where readings are made (by the poacher strategy) x how
far from the UAV (by the weather), as ``em_ppo.yml``'s ``count_factors`` fits it inside EM-PPO (``factored``).

Each is scored on held-out episodes (other seeds) by the aligned accuracy of the posterior's argmax over the
8 modes (components matched to modes by the Hungarian method, as ``evaluate_team`` does) and of the
poacher strategy read off the aligned mode, at 25 %, 50 % and 100 % of the episode, from **one UAV**'s own
evidence and from **the team**'s (the sum of all its UAVs' evidence: what fusion would give if every UAV
heard every other every step, fusion's upper bound). The supervised probe of ``benchmarks/mode_evidence.py`` is the
ceiling of any method on the same question.

Example: ``python docs/lab/studies/mixture_ceiling.py`` (or ``make benchmark-mixture-ceiling``; about 5 minutes)
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch as th
from scipy.special import softmax
from stable_baselines3.common.base_class import BaseAlgorithm

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
from em_speed import build  # benchmarks/em_speed.py: an algorithm with its zoo YAML's settings

from sb3_emmarl.common.appended.wrapping import find_wrapper
from sb3_emmarl.common.latent.belief import BeliefWrapper
from sb3_emmarl.common.latent.counts import PoissonMixture
from sb3_emmarl.common.latent.em import EStep, Transitions, transition_log_likelihoods
from sb3_emmarl.common.latent.metrics import align_components
from sb3_emmarl.common.latent.reserve_evidence import COUNT_EVIDENCE_WEIGHT, ReadingCounter
from sb3_emmarl.common.vec_env import make_vec_env
from wildlife_reserve.reserve.modes import N_MODES, STRATEGIES, WEATHERS

#: Points of the episode, as fractions of its length.
POINTS = (0.25, 0.5, 1.0)
#: Offset of the held-out episodes' seed.
TEST_SEED_OFFSET = 1_000_000


@dataclass
class Episodes:
    """Transitions of whole episodes: one row per agent-step, with the UAV's and the team's episode ids, the
    step within the episode and the episode's true mode."""

    features: np.ndarray
    actions: np.ndarray
    next_features: np.ndarray
    uav_episode: np.ndarray
    team_episode: np.ndarray
    step: np.ndarray
    mode: np.ndarray
    #: Reading counts ``(units, len(POINTS), channels, bins)`` and exposures ``(units, len(POINTS), bins)`` of each
    #: UAV-episode summed up to each of :data:`POINTS` (:class:`ReadingCounter`), with the unit's UAV and team
    #: episode ids and mode.
    counts: np.ndarray
    exposure: np.ndarray
    count_uav: np.ndarray
    count_team: np.ndarray
    count_mode: np.ndarray

    def transitions(self, team: bool) -> Transitions:
        """As E-step data; with ``team``, the agents of one reserve share their episode (EM-PPO's team pooling)."""
        return Transitions.from_numpy(self.features, self.actions, self.next_features,
                                      self.team_episode if team else self.uav_episode)


def collect(model, n_episodes: int, n_copies: int, seed: int) -> Episodes:
    """Play ``n_episodes`` (rounded up to whole rounds of ``n_copies``) of the default reserve with uniformly random
    actions; features and encoded actions as ``model``'s belief reads them."""
    venv = make_vec_env(n_copies=n_copies, seed=seed)
    wrapper = find_wrapper(model.get_env(), BeliefWrapper)
    counter = ReadingCounter.from_env(venv.unwrapped.prototype)
    n, per_copy = venv.num_envs, venv.num_envs // n_copies
    length = venv.unwrapped.prototype.max_cycles
    marks = {max(1, round(point * length)): k for k, point in enumerate(POINTS)}  # steps seen -> point
    summed_counts, summed_exposure = np.zeros((n, counter.n_channels, counter.n_bins)), np.zeros((n, counter.n_bins))
    units: list[tuple] = []  # (uav episode, team episode, mode, point, counts, exposure)
    rng = np.random.default_rng(seed)
    features = wrapper.feature_fn(venv.reset())
    modes = np.array([info["mode"] for info in venv.unwrapped.reset_infos])
    team = np.arange(n) // per_copy
    step = np.zeros(n, dtype=np.int64)
    rows: list[tuple[np.ndarray, ...]] = []
    finished, next_team = 0, n_copies
    while finished < n_episodes:
        actions = rng.integers(venv.action_space.n, size=n)
        observations, _, dones, infos = venv.step(actions)
        following = wrapper.feature_fn(observations)
        after = following.copy()  # the episode's last transition leads to its terminal observation
        seen = observations.copy()
        for i in np.flatnonzero(dones):
            seen[i] = infos[i]["terminal_observation"]
            after[i] = wrapper.feature_fn(seen[i][None])[0]
        uav = team * per_copy + np.arange(n) % per_copy
        rows.append((features, wrapper.encode_action(actions), after, uav, team.copy(), step.copy(), modes.copy()))
        features = following
        step += 1
        counts, exposure = counter(seen)
        summed_counts += counts
        summed_exposure += exposure
        for i in np.flatnonzero(np.isin(step, list(marks))):
            units.append((uav[i], team[i], modes[i], marks[step[i]], summed_counts[i].copy(), summed_exposure[i].copy()))
        for copy in np.unique(np.flatnonzero(dones) // per_copy):
            entries = slice(copy * per_copy, (copy + 1) * per_copy)
            team[entries], step[entries], next_team, finished = next_team, 0, next_team + 1, finished + 1
            summed_counts[entries], summed_exposure[entries] = 0.0, 0.0
        modes = np.array([info["mode"] for info in infos])
    venv.close()
    order = sorted(range(len(units)), key=lambda j: (units[j][0], units[j][3]))  # by unit, then point
    uav_ids, team_ids, unit_modes, _, counts, exposure = (np.array([units[j][f] for j in order]) for f in range(6))
    n_points = len(POINTS)
    return Episodes(*(np.concatenate(column) for column in zip(*rows)),
                    counts=counts.reshape(-1, n_points, *counts.shape[1:]),
                    exposure=exposure.reshape(-1, n_points, exposure.shape[-1]),
                    count_uav=uav_ids[::n_points], count_team=team_ids[::n_points], count_mode=unit_modes[::n_points])


def team_totals(episodes: Episodes, point: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Counts, exposures and modes of each team episode, summed over its UAVs up to ``POINTS[point]``."""
    teams, index = np.unique(episodes.count_team, return_inverse=True)
    counts = np.zeros((len(teams), *episodes.counts.shape[2:]))
    exposure = np.zeros((len(teams), episodes.exposure.shape[-1]))
    np.add.at(counts, index, episodes.counts[:, point])
    np.add.at(exposure, index, episodes.exposure[:, point])
    modes = np.zeros(len(teams), dtype=np.int64)
    modes[index] = episodes.count_mode
    return counts, exposure, modes


def fit_counts(seed: int, train: Episodes, told: bool, factors: tuple[int, int] | None = None,
               n_rings: int = 1) -> PoissonMixture:
    """The reading-count mixture (K = 8) on the training episodes' team totals: annealed EM, or told the modes; with
    ``factors``, its rates factored as where x how far (``n_rings`` rings per block)."""
    counts, exposure, modes = team_totals(train, len(POINTS) - 1)
    mixture = PoissonMixture(N_MODES, *counts.shape[1:], factors=factors, n_rings=n_rings)
    return mixture.fit_told(counts, exposure, modes) if told else mixture.fit(counts, exposure, seed=seed)


def score(posterior: np.ndarray, modes: np.ndarray) -> tuple[float, float]:
    """Aligned mode and strategy accuracy of the posteriors' argmax."""
    guess = align_components(posterior, modes, N_MODES)[posterior.argmax(axis=1)]
    return float((guess == modes).mean()), float((guess // len(WEATHERS) == modes // len(WEATHERS)).mean())


def count_accuracies(mixture: PoissonMixture, test: Episodes) -> dict[str, float]:
    """As :func:`accuracies`, for the reading-count mixture."""
    scores = {}
    for k, point in enumerate(POINTS):
        team = team_totals(test, k)
        for source, (counts, exposure, modes) in (("one UAV", (test.counts[:, k], test.exposure[:, k], test.count_mode)),
                                                   ("team", team)):
            mode, strategy = score(mixture.posterior(counts, exposure), modes)
            scores[f"{source} mode {point:.0%}"], scores[f"{source} strategy {point:.0%}"] = mode, strategy
    return scores


class ToldEStep(EStep):
    """An :class:`EStep` whose responsibilities are each episode's true mode (component ``k`` is mode ``k``; no
    component is ever re-seeded).

    :param modes: ``{episode id: true mode}`` of every episode it will see
    :param kwargs: :class:`EStep`'s arguments
    """

    def __init__(self, modes: dict[int, int], **kwargs) -> None:
        super().__init__(**{**kwargs, "starved_share": 0.0})
        self.modes = modes

    def responsibilities(self, data: Transitions) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        _, index, evidence = super().responsibilities(data)
        # Row g of the evidence is the g-th episode id in sorted order (``sum_by_group``'s grouping).
        told = th.tensor([self.modes[int(e)] for e in th.unique(data.episodes)])
        return th.log_softmax(-30.0 * (th.arange(evidence.shape[1])[None] != told[:, None]).float(), -1), index, evidence


def fit(seed: int, train: Episodes, e_steps: int, told: bool) -> BaseAlgorithm:
    """EM-PPO's latent model (``em_ppo.yml``), fitted by ``e_steps`` of its E-step on all of ``train``."""
    model = build("em_ppo", seed=seed, n_copies=1)
    latent = model.policy.latent_model
    if told and latent.n_components < N_MODES:
        raise ValueError(f"told needs n_components >= {N_MODES}, em_ppo.yml has {latent.n_components}")
    config = model.latent_config
    kwargs = {**config.e_step_kwargs, "window": 1, "likelihood_temperature": config.likelihood_temperature,
              "estimator": config.estimator, "seed": seed, "count_weight": COUNT_EVIDENCE_WEIGHT}
    if told:
        modes = dict(zip(train.team_episode.tolist(), train.mode.tolist()))
        e_step = ToldEStep(modes, latent_model=latent, **kwargs)
    else:
        e_step = EStep(latent, **kwargs)
    e_step.add(train.transitions(team=config.team_pooling))
    for _ in range(e_steps):
        e_step.step()
    return model


def accuracies(model, test: Episodes) -> dict[str, float]:
    """Aligned mode and strategy accuracy from one UAV's and from the team's evidence, at each of :data:`POINTS`."""
    latent, beta = model.policy.latent_model, model.latent_config.likelihood_temperature
    log_lik = transition_log_likelihoods(latent, test.transitions(team=False)).double().numpy()
    log_prior = latent.log_prior.double().numpy()
    length = int(test.step.max()) + 1
    scores = {}
    for point in POINTS:
        seen = test.step < max(1, round(point * length))
        for source, ids in (("one UAV", test.uav_episode), ("team", test.team_episode)):
            keys, index = np.unique(ids[seen], return_inverse=True)
            evidence = np.zeros((len(keys), len(log_prior)))
            np.add.at(evidence, index, beta * log_lik[seen])
            modes = np.zeros(len(keys), dtype=np.int64)
            modes[index] = test.mode[seen]
            mode, strategy = score(softmax(evidence + log_prior, axis=1), modes)
            scores[f"{source} mode {point:.0%}"], scores[f"{source} strategy {point:.0%}"] = mode, strategy
    return scores


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--train-episodes", type=int, default=200, help="training episodes (random actions)")
    parser.add_argument("--test-episodes", type=int, default=200, help="held-out episodes")
    parser.add_argument("--e-steps", type=int, default=20, help="E-steps over all the training episodes")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="seeds of the model and its E-step")
    parser.add_argument("--n-copies", type=int, default=8, help="reserves played at once")
    args = parser.parse_args(argv)
    for name in ("train_episodes", "test_episodes", "e_steps", "n_copies"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    th.set_num_threads(1)
    start = time.perf_counter()
    reader = build("em_ppo", seed=0, n_copies=1)
    train = collect(reader, args.train_episodes, args.n_copies, seed=0)
    test = collect(reader, args.test_episodes, args.n_copies, seed=TEST_SEED_OFFSET)
    rows = {}
    for fitting in ("em", "told"):
        runs = [accuracies(fit(seed, train, args.e_steps, told=fitting == "told"), test) for seed in args.seeds]
        rows["transitions", fitting] = {key: np.array([run[key] for run in runs]) for key in runs[0]}
    # em_ppo.yml's, or strategy x weather
    factors = tuple(reader.latent_config.count_factors or (len(STRATEGIES), len(WEATHERS)))
    rings = find_wrapper(reader.get_env(), BeliefWrapper).counter.n_rings
    for family, family_factors in (("counts", None), ("factored", factors)):
        for fitting in ("em", "told"):
            runs = [count_accuracies(fit_counts(seed, train, fitting == "told", family_factors, rings), test)
                    for seed in args.seeds]
            rows[family, fitting] = {key: np.array([run[key] for run in runs]) for key in runs[0]}
    modes = np.unique(test.team_episode, return_index=True)[1]
    commonest = np.bincount(test.mode[modes], minlength=N_MODES).max() / len(modes)
    strategies = np.bincount(test.mode[modes] // len(WEATHERS)).max() / len(modes)
    print(f"transitions: em_ppo.yml's latent model ({args.e_steps} E-steps); counts: the reading-count mixture (K = 8, "
          f"annealed EM); factored: the same with rates factored as where x how far, factors {list(factors)} (em_ppo.yml's "
          f"count_factors); the default reserve, uniformly random actions: {len(np.unique(train.team_episode))} training "
          f"and {len(modes)} held-out episodes, seeds {args.seeds}; aligned accuracy, mean +- std over seeds; commonest "
          f"mode {commonest:.3f}, commonest strategy {strategies:.3f}")
    print(f"{'model':<12}{'fitting':<8}{'source':<9}{'what':<10}" + "".join(f"{f'{p:.0%}':>15}" for p in POINTS))
    for (family, fitting), scores in rows.items():
        for source in ("one UAV", "team"):
            for what in ("mode", "strategy"):
                cells = [scores[f"{source} {what} {p:.0%}"] for p in POINTS]
                print(f"{family:<12}{fitting:<8}{source:<9}{what:<10}"
                      + "".join(f"{c.mean():>8.3f} +- {c.std():.3f}" for c in cells))
    print(f"wall time {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
