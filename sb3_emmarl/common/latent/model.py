"""The latent model: encoder ``q_phi(z | h_t)``, decoder ``p(x_{t+1}, r_t | x_t, a_t, z)``, mixture prior ``pi``.

``z`` is categorical with ``K`` components. The ELBO of one agent-step (paper, section 4.2.1) is

    ELBO = E_{q_phi(z | h_t)}[ sum_j log p(x_{j+1}, r_j | x_j, a_j, z) ] - KL( q_phi(z | h_t) || pi )

where ``j`` runs over the transitions inside the history window and the next one (``j = t``, the
paper's ``log p(x_{t+1} | o_t, a_t, z)``): reconstructing the whole recent stretch with one ``z``, as
the episode's hidden mode does, is what keeps the components from collapsing into one.

with two estimators of the expectation: ``"enumerate"`` sums over the ``K`` components exactly;
``"gumbel"`` feeds one Gumbel-softmax relaxed sample of ``z`` (temperature ``tau``) to the decoder,
as the paper does. The KL term is exact in both. ``pi`` is not learned by gradient: the E-step sets
it in closed form to the mean responsibilities (:meth:`LatentModel.set_prior`).
"""

from __future__ import annotations

import math

import torch as th
import torch.nn.functional as F
from torch import nn

from sb3_emmarl.common.latent.history import HistoryLayout


def gaussian_log_density(target: th.Tensor, mean: th.Tensor, log_std: th.Tensor) -> th.Tensor:
    """Diagonal Gaussian log-density, summed over the last dimension."""
    return (-0.5 * ((target - mean) / log_std.exp()) ** 2 - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)


def sum_by_group(values: th.Tensor, groups: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """Sum the rows of ``values`` within each group; every row gets its group's sum and its group's size."""
    _, index, counts = th.unique(groups, return_inverse=True, return_counts=True)
    summed = th.zeros(len(counts), values.shape[1], device=values.device, dtype=values.dtype).index_add(0, index, values)
    return summed[index], counts[index]


class LatentModel(nn.Module):
    """Encoder, decoder and prior of the categorical latent variable, shared by all agents.

    :param layout: where features, actions and rewards sit in the history window
    :param n_components: ``K``, the number of latent components
    :param encoder_hidden: hidden size of the GRU encoder
    :param decoder_hidden: hidden layer sizes of the decoder's shared trunk (each component has its own linear read-out)
    """

    def __init__(self, layout: HistoryLayout, n_components: int = 4, encoder_hidden: int = 64,
                 decoder_hidden: tuple[int, ...] = (64, 64)) -> None:
        super().__init__()
        if n_components < 1:
            raise ValueError(f"n_components must be >= 1, got {n_components}")
        self.layout = layout
        self.n_components = n_components
        self.encoder = nn.GRU(layout.step_dim, encoder_hidden, batch_first=True)
        self.encoder_head = nn.Linear(encoder_hidden, n_components)
        target_dim = layout.feature_dim + 1  # change of the features, and the reward
        layers: list[nn.Module] = []
        size = layout.feature_dim + layout.action_dim
        for hidden in decoder_hidden:
            layers += [nn.Linear(size, hidden), nn.Tanh()]
            size = hidden
        # A trunk shared by the components, then one linear read-out per component.
        self.decoder_trunk = nn.Sequential(*layers)
        self.decoder_weight = nn.Parameter(th.randn(n_components, size, target_dim) / math.sqrt(size))
        self.decoder_bias = nn.Parameter(th.zeros(n_components, target_dim))
        self.decoder_log_std = nn.Parameter(th.zeros(n_components, target_dim))
        self.register_buffer("log_prior", th.full((n_components,), -math.log(n_components)))
        #: When True, features extractors read a posterior written into the observation instead of running the encoder.
        self.precomputed = False

    # ------------------------------------------------------------------ encoder q_phi(z | h_t)
    def posterior_logits(self, window: th.Tensor) -> th.Tensor:
        """``log q_phi(z | h_t)`` for history windows ``(B, H, step_dim)`` -> ``(B, K)`` (normalised)."""
        _, hidden = self.encoder(window)
        return F.log_softmax(self.encoder_head(hidden[-1]), dim=-1)

    def posterior(self, window: th.Tensor) -> th.Tensor:
        """``q_phi(z | h_t)`` as probabilities ``(B, K)``."""
        return self.posterior_logits(window).exp()

    # ------------------------------------------------------------------ decoder p(x_{t+1}, r_t | x_t, a_t, z)
    def component_means(self, features: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """Each component's predicted mean of the target: ``(B, K, d_x + 1)``."""
        hidden = self.decoder_trunk(th.cat([features, actions], dim=-1))
        return th.einsum("bh,khd->bkd", hidden, self.decoder_weight) + self.decoder_bias

    def log_likelihood_per_component(self, features: th.Tensor, actions: th.Tensor, target: th.Tensor) -> th.Tensor:
        """Gaussian ``log p(target | x_t, a_t, z = k)`` for every component: ``(B, K)``."""
        return gaussian_log_density(target[:, None, :], self.component_means(features, actions), self.decoder_log_std)

    def log_likelihood(self, features: th.Tensor, actions: th.Tensor, target: th.Tensor, z: th.Tensor) -> th.Tensor:
        """Gaussian log-density of ``target`` given a one-hot or relaxed ``z`` ``(B, K)``, means and log-stds mixed by it."""
        mean = (z[:, :, None] * self.component_means(features, actions)).sum(1)
        return gaussian_log_density(target, mean, z @ self.decoder_log_std)

    # ------------------------------------------------------------------ ELBO
    def transitions(self, window: th.Tensor, next_slot: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        """The transitions ``(x_j, a_j) -> (x_{j+1}, r_j)`` of the window ``h_t`` extended by the next step's slot.

        :return: features ``(B, H, d_x)``, actions ``(B, H, d_a)``, targets ``(B, H, d_x + 1)`` (the change
            ``x_{j+1} - x_j`` and ``r_j``: modelling the change keeps every component's start alike) and a mask
            ``(B, H)`` of transitions whose both ends are real steps (not padding)
        """
        steps = th.cat([window, next_slot[:, None, :]], dim=1)  # (B, H + 1, step_dim)
        x, a, r, valid = self.layout.slot_parts(steps)
        # The decoder predicts the change of the features (x_{j+1} - x_j) and the reward.
        target = th.cat([x[:, 1:] - x[:, :-1], r[:, 1:, None]], dim=-1)
        return x[:, :-1], a[:, 1:], target, valid[:, :-1] * valid[:, 1:]

    def stretch_log_likelihood(self, window: th.Tensor, next_slot: th.Tensor) -> th.Tensor:
        """``sum_j log p(x_{j+1}, r_j | x_j, a_j, z = k)`` over the window's transitions and the next one: ``(B, K)``."""
        features, actions, target, mask = self.transitions(window, next_slot)
        batch, steps = features.shape[:2]
        flat = lambda t: t.reshape(batch * steps, -1)  # noqa: E731
        log_lik = self.log_likelihood_per_component(flat(features), flat(actions), flat(target))
        return (log_lik.view(batch, steps, self.n_components) * mask[..., None]).sum(1)

    def responsibilities(self, window: th.Tensor, next_slot: th.Tensor, groups: th.Tensor | None = None) -> th.Tensor:
        """Exact posterior of ``z`` given the stretch's transitions: ``log r_k ∝ log pi_k + sum_j log p(... | z = k)``.

        With ``groups``, the agents of a group share one team posterior (their evidence adds up).
        """
        return self.responsibilities_from(self.stretch_log_likelihood(window, next_slot), groups)

    def responsibilities_from(self, log_likelihood: th.Tensor, groups: th.Tensor | None = None) -> th.Tensor:
        """:meth:`responsibilities` from a computed :meth:`stretch_log_likelihood` ``(B, K)`` (no gradient flows back)."""
        log_joint = log_likelihood.detach()
        if groups is not None:
            log_joint = sum_by_group(log_joint, groups)[0]
        return F.log_softmax(log_joint + self.log_prior, dim=-1)

    def elbo(
        self,
        window: th.Tensor,
        next_slot: th.Tensor,
        estimator: str = "enumerate",
        temperature: float = 1.0,
        groups: th.Tensor | None = None,
        log_likelihood: th.Tensor | None = None,
        log_q: th.Tensor | None = None,
    ) -> dict[str, th.Tensor]:
        """Per-sample ELBO with the encoder's posterior, its reconstruction and KL terms.

        ``recon = E_q(z | h_t)[ sum_j log p(x_{j+1}, r_j | x_j, a_j, z) ]`` over the transitions of the window
        ``h_t`` and the next one (``j = t``), which is ``log p(x_{t+1}, r_t | x_t, a_t, z)`` when ``H = 1``.

        :param window: histories ``h_t`` ``(B, H, step_dim)``
        :param next_slot: the slot of step ``t + 1`` ``(B, step_dim)``: ``x_{t+1}``, ``a_t``, ``r_t``
        :param estimator: ``"enumerate"`` (exact over ``K``) or ``"gumbel"`` (one relaxed sample of ``z``)
        :param temperature: Gumbel-softmax temperature
        :param groups: optional ``(B,)`` ids of agents to pool into one team posterior (same copy and step)
        :param log_likelihood: the :meth:`stretch_log_likelihood` of these samples, when already computed
        :param log_q: ``log q_phi(z | h_t)`` of these samples (pooled, with ``groups``), when already computed
        :return: ``elbo``, ``recon``, ``kl`` ``(B,)`` and ``log_q`` ``(B, K)``
        """
        if log_q is None:
            log_q = self.posterior_logits(window)
            if groups is not None:
                log_q = self.pool(log_q, groups)
        q = log_q.exp()
        recon = self.expected_log_likelihood(window, next_slot, q, estimator, temperature, log_likelihood)
        kl = (q * (log_q - self.log_prior)).sum(-1)
        return {"elbo": recon - kl, "recon": recon, "kl": kl, "log_q": log_q}

    def expected_log_likelihood(self, window: th.Tensor, next_slot: th.Tensor, weights: th.Tensor,
                                estimator: str = "enumerate", temperature: float = 1.0,
                                log_likelihood: th.Tensor | None = None) -> th.Tensor:
        """``E_{z ~ weights}[ sum_j log p(x_{j+1}, r_j | x_j, a_j, z) ]``: exact over ``K``, or one Gumbel-softmax sample.

        :param log_likelihood: the :meth:`stretch_log_likelihood` of these samples when already computed
            (``"enumerate"`` then reuses it)
        """
        if estimator == "enumerate":
            if log_likelihood is None:
                log_likelihood = self.stretch_log_likelihood(window, next_slot)
            return (weights * log_likelihood).sum(-1)
        if estimator == "gumbel":
            features, actions, target, mask = self.transitions(window, next_slot)
            batch, steps = features.shape[:2]
            flat = lambda t: t.reshape(batch * steps, -1)  # noqa: E731
            z = F.gumbel_softmax(weights.clamp_min(1e-8).log(), tau=temperature, hard=False).repeat_interleave(steps, dim=0)
            return (self.log_likelihood(flat(features), flat(actions), flat(target), z).view(batch, steps) * mask).sum(1)
        raise ValueError(f"estimator must be 'enumerate' or 'gumbel', got {estimator!r}")

    def pool(self, log_q: th.Tensor, groups: th.Tensor) -> th.Tensor:
        """Team posterior of each group: ``q_team(z) ∝ pi(z) * prod_i q_i(z) / pi(z)``, given to each member.

        :param log_q: per-agent ``log q`` ``(B, K)``
        :param groups: ``(B,)`` integer group ids
        """
        summed, counts = sum_by_group(log_q, groups)
        return F.log_softmax(summed - (counts[:, None] - 1) * self.log_prior, dim=-1)

    # ------------------------------------------------------------------ prior pi
    @th.no_grad()
    def set_prior(self, responsibilities: th.Tensor, floor: float = 1e-4) -> None:
        """M-step of the mixture weights in closed form: ``pi = mean responsibilities`` (floored, renormalised)."""
        pi = responsibilities.mean(dim=0).clamp_min(floor)
        self.log_prior.copy_((pi / pi.sum()).log())

    def prior(self) -> th.Tensor:
        return self.log_prior.exp()

    @th.no_grad()
    def split_component(self, dead: int, source: int, noise: float = 0.05, generator: th.Generator | None = None) -> None:
        """Re-seed a starved component as a perturbed copy of ``source``; the two share ``source``'s prior mass.

        Mixture fits starve components whose first fits were poor; splitting the busiest component lets
        the two copies divide what it explains (split-and-merge EM).
        """
        def jitter(like: th.Tensor) -> th.Tensor:
            return noise * th.randn(like.shape, generator=generator).to(like.device) * (like.abs().mean() + 1e-3)

        for param in (self.decoder_weight, self.decoder_bias, self.decoder_log_std):
            param[dead] = param[source] + jitter(param[source])
        self.encoder_head.weight[dead] = self.encoder_head.weight[source] + jitter(self.encoder_head.weight[source])
        self.encoder_head.bias[dead] = self.encoder_head.bias[source]
        prior = self.prior()
        prior[dead] = prior[source] = prior[source] / 2
        self.log_prior.copy_((prior / prior.sum()).log())
