"""Does a policy read its belief? Measures of how much the actions depend on the belief, and of whether the latent
components keep their identity from one E-step to the next.

- :func:`permute_beliefs`: augmented observations whose beliefs are moved to other components (a cyclic shift).
- :func:`belief_use`: how far the policy's actions move when the belief is permuted, over given observations: the mean
  ``KL(pi(. | o, q) || pi(. | o, shift(q)))`` for a stochastic policy (PPO's), the mean squared change of the action
  for a deterministic one (DDPG's actor). Zero for a policy that ignores its belief; a policy that acts on a right
  belief moves far (for a one-hot-like belief, as far as it moves between the modes).
- :func:`assignment_agreement`: the share of episodes whose most likely component is the same under two sets of
  responsibilities (``kept``), and the same after the best one-to-one relabelling (``matched``, Hungarian
  matching): ``kept`` well below ``matched`` means the components were relabelled, which a policy that learnt to
  read component ``k`` as a mode cannot follow.

EM-PPO logs :func:`belief_use` and the entropy of the beliefs with every E-step (``latent/belief_use``,
``latent/belief_entropy``), the E-step its agreement (``latent/assignment_kept``, ``latent/assignment_matched``);
:func:`~sb3_emmarl.common.evaluation.evaluate_team` adds ``belief_use`` to each episode's record.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast, overload

import numpy as np
import torch as th
from scipy.optimize import linear_sum_assignment
from stable_baselines3.common.policies import BasePolicy

#: Observations read per measurement of :func:`belief_use` (evenly spaced rows of larger batches): the measurement is
#: a mean, and a forward pass per component over a whole rollout of the reserve would cost as much as an epoch of PPO.
BELIEF_USE_ROWS = 1024


@overload
def permute_beliefs(observations: th.Tensor, n_components: int, shift: int = 1) -> th.Tensor: ...


@overload
def permute_beliefs(observations: np.ndarray, n_components: int, shift: int = 1) -> np.ndarray: ...


def permute_beliefs(observations: np.ndarray | th.Tensor, n_components: int, shift: int = 1) -> np.ndarray | th.Tensor:
    """``observations`` (``(..., obs_dim + K)``, the belief last) with each belief moved ``shift`` components on:
    the mass of component ``k`` goes to ``(k + shift) % K``. A copy; the observations' own part is unchanged."""
    if isinstance(observations, th.Tensor):
        out = observations.clone()
        out[..., -n_components:] = th.roll(observations[..., -n_components:], shift, dims=-1)
        return out
    array = np.array(observations, copy=True)
    array[..., -n_components:] = np.roll(array[..., -n_components:], shift, axis=-1)
    return array


def belief_use(policy: BasePolicy, observations: np.ndarray | th.Tensor, n_components: int,
               max_rows: int = BELIEF_USE_ROWS) -> float:
    """How much the policy's actions depend on the belief (see the module's text), averaged over every cyclic shift
    of the components and over at most ``max_rows`` of the augmented ``observations`` ``(N, obs_dim + K)``.

    :param policy: an SB3 policy with ``get_distribution`` (actor-critic) or ``actor`` (TD3/DDPG)
    :param observations: augmented observations, the belief last
    :param n_components: ``K``
    :param max_rows: observations read at most (evenly spaced rows beyond that: nothing is drawn from a generator, so
        measuring leaves a run's random numbers as they were)
    :return: mean KL (stochastic policies) or mean squared action change (deterministic actors); 0.0 when ``K = 1``
    """
    flat = np.asarray(observations, dtype=np.float32).reshape(-1, np.shape(observations)[-1])
    if n_components < 2 or len(flat) == 0:
        return 0.0
    if len(flat) > max_rows:
        flat = flat[:: -(-len(flat) // max_rows)]
    obs = th.as_tensor(flat, device=policy.device)
    shifts = range(1, n_components)
    with th.no_grad():
        if hasattr(policy, "get_distribution"):  # (duck-typed: torch's Module typing only knows it as an attribute)
            get_distribution = cast("Callable[[th.Tensor], Any]", policy.get_distribution)
            base = get_distribution(obs).distribution
            values = [th.distributions.kl_divergence(base, get_distribution(permute_beliefs(obs, n_components, s))
                                                     .distribution) for s in shifts]
            values = [v.sum(-1) if v.dim() > 1 else v for v in values]  # (diagonal Gaussians: per dimension)
        else:
            actor = cast("Callable[[th.Tensor], th.Tensor]", policy.actor)
            base = actor(obs)
            values = [(actor(permute_beliefs(obs, n_components, s)) - base).square().sum(-1) for s in shifts]
    return float(th.stack(values).mean())


def belief_entropy(beliefs: np.ndarray) -> float:
    """Mean entropy (nats) of beliefs ``(N, K)``: ``log K`` for uniform ones, 0 for one-hot ones."""
    beliefs = np.asarray(beliefs, dtype=np.float64)
    if beliefs.size == 0:
        return 0.0
    return float(-(beliefs * np.log(np.clip(beliefs, 1e-12, None))).sum(-1).mean())


def assignment_agreement(before: np.ndarray, after: np.ndarray, n_components: int) -> tuple[float, float]:
    """Agreement of two assignments of the same episodes to components (``(S,)`` ints in ``[0, K)``).

    :return: ``(kept, matched)``: the share of episodes assigned the same component, and the same share after the
        one-to-one relabelling of ``after`` that maximises it (Hungarian matching); ``(1.0, 1.0)`` for no episodes
    """
    before, after = np.asarray(before, dtype=np.int64), np.asarray(after, dtype=np.int64)
    if before.shape != after.shape or before.ndim != 1:
        raise ValueError(f"before and after must be 1-D arrays of one shape, got {before.shape} and {after.shape}")
    if len(before) == 0:
        return 1.0, 1.0
    if before.min() < 0 or after.min() < 0 or max(before.max(), after.max()) >= n_components:
        raise ValueError(f"assignments must lie in [0, {n_components}), got [{min(before.min(), after.min())}, "
                         f"{max(before.max(), after.max())}]")
    table = np.zeros((n_components, n_components))
    np.add.at(table, (after, before), 1.0)
    rows, cols = linear_sum_assignment(-table)
    return float((before == after).mean()), float(table[rows, cols].sum() / len(before))
