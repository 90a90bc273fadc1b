"""The latent model: a mixture of transition models ``p(x_{t+1} | x_t, a_t, z)`` and its prior ``pi``.

``z`` is categorical with ``K`` components and holds for a whole episode, as the environment's hidden mode
does. The model is the decoder of the paper (section 4.2.1, ``p(x_{t+1} | o_t, a_t, z)``); the posterior of
``z`` given everything an agent has seen since its episode began is then exact:

    log q(z = k | o_{1:t}, a_{1:t-1}) = log pi_k + beta * sum_{j < t} log p(x_{j+1} | x_j, a_j, z = k) + const

the filtering posterior that :mod:`~sb3_emmarl.common.latent.belief` keeps up to date one transition at a
time (constant cost per step). ``beta`` (``likelihood_temperature``, default 1) tempers the evidence: a
decoder that is misspecified (a Gaussian over features that are not Gaussian) is overconfident, and
``beta < 1`` keeps the belief calibrated. The readings (below) are modelled exactly, and their terms are not
tempered. Rewards are not modelled: SB3's ``predict`` never sees them, and the belief must be computable from what an
agent observes when it acts.

The E-step (:mod:`~sb3_emmarl.common.latent.em`) fits the decoder to whole episodes by EM and sets ``pi``
to the mean responsibilities.
"""

from __future__ import annotations

import math
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
import torch.nn.functional as F
from numba import njit
from torch import nn

from sb3_emmarl.common.latent.layout import LatentLayout

if TYPE_CHECKING:
    from sb3_emmarl.common.latent.evidence import CountEvidence

#: Bounds of the decoder's log standard deviations: a feature that never changes would otherwise drive its
#: deviation to zero and its log-likelihood, hence every belief, to infinity.
LOG_STD_BOUNDS = (-3.0, 2.0)


#: Standard deviation of the noise on the reading-count model's first log-rates (they break the components' symmetry).
COUNT_START_NOISE = 0.1


def gaussian_log_normalizer(log_std: th.Tensor) -> th.Tensor:
    """``sum log_std + d / 2 log 2 pi``: what a diagonal Gaussian's log-density subtracts from ``-|z|^2 / 2``."""
    return log_std.sum() + 0.5 * math.log(2 * math.pi) * log_std.shape[-1]


def gaussian_log_density(target: th.Tensor, mean: th.Tensor, log_std: th.Tensor) -> th.Tensor:
    """Diagonal Gaussian log-density, summed over the last dimension.

    The constant part (:func:`gaussian_log_normalizer`) is summed once, not per element: on the E-step's
    ``(N, K, d_x)`` arrays each full-size operation fewer is a pass over tens of megabytes fewer.
    """
    z = (target - mean) * (-log_std).exp()
    return -0.5 * (z * z).sum(-1) - gaussian_log_normalizer(log_std)


def sum_by_group(values: th.Tensor, groups: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """Sum the rows of ``values`` ``(N, K)`` within each group: ``(G, K)`` sums and, per row, its group's index."""
    _, index = th.unique(groups, return_inverse=True)
    summed = th.zeros(int(index.max()) + 1 if len(index) else 0, values.shape[1], device=values.device,
                      dtype=values.dtype).index_add(0, index, values)
    return summed, index


def _changed_on_load(module: nn.Module, incompatible_keys: Any) -> None:
    """``load_state_dict``'s post-hook: a load writes the parameters (a module-level function, so the model pickles)."""
    assert isinstance(module, LatentModel)
    module.mark_changed()


def _changed_after_step(model: LatentModel, optimizer: th.optim.Optimizer, args: Any, kwargs: Any) -> None:
    """An optimizer's step post-hook (:meth:`LatentModel.watch`): the step wrote the model's parameters."""
    model.mark_changed()


class LatentModel(nn.Module):
    """The transition models ``p(x_{t+1} | x_t, a_t, z)`` of the components and the prior ``pi``, shared by all agents.

    A trunk shared by the components reads ``(x_t, a_t)``; the mean of ``x_{t+1}`` is ``x_t`` plus a change read
    out linearly from it, by a read-out shared by the components plus one of each component's own; the standard
    deviations are shared. What every mode has in common is thus learnt once, from all the data, and the
    components differ only in how the modes differ: otherwise the component that happens to be fitted on most
    data models the common part best and wins every episode (observed on the reserve).

    The layout's *reading* features (``reading_features``: read afresh each step, independent given the mode) are
    modelled as what they are: a Gaussian whose mean is a bias shared by the components plus each component's own,
    neither ``x_t`` nor the trunk entering it (their read-out weights are masked to zero). For Gaussian readings of a
    mode-dependent mean, as ZonePatrol's zone readings, this is the exact likelihood, so that the belief from them is
    the exact posterior once the means are fitted; the transition form fitted to the same readings must learn to
    subtract ``x_t`` through the trunk, and reads them less well (docs/em.md, "Readings").

    Whatever writes the model's parameters or buffers announces it (:meth:`mark_changed`), so that the beliefs'
    compiled copy (:class:`StepLikelihood`) follows: the closed-form updates here, ``load_state_dict`` (a post-hook)
    and the steps of every optimizer :meth:`watch` was given (the E-step's) do; a write elsewhere must call it.

    :param layout: the latent layout (feature and action sizes, ``K``, decoder sizes)
    """

    # Buffers (register_buffer), declared for the type checker; count_log_rates is None without the count model,
    # transition_mask (1 for a transition feature, 0 for a reading) None without readings.
    log_prior: th.Tensor
    count_log_rates: th.Tensor | None
    transition_mask: th.Tensor | None

    def __init__(self, layout: LatentLayout) -> None:
        super().__init__()
        self.layout = layout
        self.n_components = k = layout.n_components
        layers: list[nn.Module] = []
        size = layout.feature_dim + layout.action_dim
        for hidden in layout.decoder_hidden:
            layers += [nn.Linear(size, hidden), nn.Tanh()]
            size = hidden
        d_x = layout.feature_dim
        self.decoder_trunk = nn.Sequential(*layers)
        self.decoder_shared = nn.Linear(size, d_x)
        self.decoder_weight = nn.Parameter(0.3 * th.randn(k, size, d_x) / math.sqrt(size))
        self.decoder_bias = nn.Parameter(0.03 * th.randn(k, d_x))
        self.decoder_log_std = nn.Parameter(th.zeros(d_x))
        self.register_buffer("log_prior", th.full((k,), -math.log(k)))
        if layout.count_bins:
            # The reading-count model's log-rates (counts.py), set in closed form by the E-step. They start equal up
            # to a little noise, so that the first E-steps' responsibilities already differ by the counts.
            shape = (k, layout.count_channels, layout.count_bins)
            self.register_buffer("count_log_rates", COUNT_START_NOISE * th.randn(shape))
        else:
            self.count_log_rates = None
        if layout.reading_features:
            mask = th.ones(d_x)
            mask[list(layout.reading_features)] = 0.0
            self.register_buffer("transition_mask", mask)
        else:
            self.transition_mask = None
        #: bumped by :meth:`mark_changed` whenever the parameters or buffers are written (see :meth:`version`)
        self.revision = 0
        self._tensors: list[th.Tensor] | None = None
        self.register_load_state_dict_post_hook(_changed_on_load)

    def component_means(self, features: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """Each component's predicted mean of ``x_{t+1}``: ``(B, K, d_x)``, as ``x_t`` plus a predicted change
        (a residual: what stays put costs the components nothing to model)."""
        hidden = self.decoder_trunk(th.cat([features, actions], dim=-1))
        mask = self.transition_mask
        if mask is None:
            shared = features + self.decoder_shared(hidden)
            return shared[:, None, :] + th.einsum("bh,khd->bkd", hidden, self.decoder_weight) + self.decoder_bias
        shared = (features + hidden @ self.decoder_shared.weight.T) * mask + self.decoder_shared.bias
        return shared[:, None, :] + th.einsum("bh,khd->bkd", hidden, self.decoder_weight * mask) + self.decoder_bias

    def log_std(self) -> th.Tensor:
        """The log standard deviations ``(d_x,)``, within :data:`LOG_STD_BOUNDS`."""
        return self.decoder_log_std.clamp(*LOG_STD_BOUNDS)

    def transition_log_likelihood(self, features: th.Tensor, actions: th.Tensor, next_features: th.Tensor) -> th.Tensor:
        """``log p(x_{t+1} | x_t, a_t, z = k)`` for every component: ``(B, K)``.

        :func:`gaussian_log_density` of :meth:`component_means`, computed with the deviations folded into the
        small read-out weights first, so that the ``(B, K, d_x)`` part is one matrix product and two passes (the
        E-step's cost is mostly these arrays)."""
        hidden = self.decoder_trunk(th.cat([features, actions], dim=-1))
        log_std = self.log_std()
        inv_std = (-log_std).exp()
        k, size, d_x = self.decoder_weight.shape
        mask = self.transition_mask
        if mask is None:
            own = (next_features - features - self.decoder_shared(hidden)) * inv_std  # (B, d_x)
            weight = (self.decoder_weight * inv_std).permute(1, 0, 2).reshape(size, k * d_x)
        else:  # (readings: their means are the biases alone)
            own = (next_features - (features + hidden @ self.decoder_shared.weight.T) * mask
                   - self.decoder_shared.bias) * inv_std
            weight = (self.decoder_weight * (mask * inv_std)).permute(1, 0, 2).reshape(size, k * d_x)
        z = own[:, None, :] - th.addmm((self.decoder_bias * inv_std).reshape(-1), hidden, weight).view(-1, k, d_x)
        return -0.5 * z.square().sum(-1) - gaussian_log_normalizer(log_std)

    def mixed_log_likelihood(self, features: th.Tensor, actions: th.Tensor, next_features: th.Tensor,
                             z: th.Tensor) -> th.Tensor:
        """Log-density of ``x_{t+1}`` under a one-hot or relaxed ``z`` ``(B, K)`` (the means mixed by it)."""
        mean = (z[:, :, None] * self.component_means(features, actions)).sum(1)
        return gaussian_log_density(next_features, mean, self.log_std())

    @property
    def has_counts(self) -> bool:
        """Whether the model has the count term (the environment's plug-in counts readings: on the reserve)."""
        return self.count_log_rates is not None

    def count_log_likelihood(self, counts: th.Tensor, exposure: th.Tensor) -> th.Tensor:
        """``(B, K)`` log-likelihood of summed reading counts ``(B, channels * bins)`` and exposures ``(B, bins)``
        (:meth:`~sb3_emmarl.common.latent.counts.PoissonMixture.log_likelihood`, in torch)."""
        assert self.count_log_rates is not None, "the model has no reading-count term"
        log_rates = self.count_log_rates.flatten(1)  # (K, channels * bins)
        return counts @ log_rates.T - exposure @ self.count_log_rates.exp().sum(1).T

    @th.no_grad()
    def set_count_rates(self, rates: th.Tensor) -> None:
        """The E-step's closed-form update of the reading-count rates ``(K, channels, bins)`` (all > 0)."""
        assert self.count_log_rates is not None, "the model has no reading-count term"
        self.count_log_rates.copy_(rates.log())
        self.mark_changed()

    def posterior_from(self, evidence: th.Tensor) -> th.Tensor:
        """``log q(z)`` from summed (tempered) log-likelihoods ``(B, K)``: ``log_softmax(log pi + evidence)``."""
        return F.log_softmax(evidence + self.log_prior, dim=-1)

    # ------------------------------------------------------------------ prior pi
    @th.no_grad()
    def set_prior(self, responsibilities: th.Tensor, floor: float = 1e-4) -> None:
        """The E-step's closed-form update of the mixture weights: ``pi = mean responsibilities`` (floored)."""
        pi = responsibilities.mean(dim=0).clamp_min(floor)
        self.log_prior.copy_((pi / pi.sum()).log())
        self.mark_changed()

    def prior(self) -> th.Tensor:
        return self.log_prior.exp()

    def mark_changed(self) -> None:
        """Announce a write to the parameters or buffers: :meth:`version` changes."""
        self.revision += 1
        self._tensors = None

    def watch(self, optimizer: th.optim.Optimizer) -> None:
        """Call :meth:`mark_changed` after every step of ``optimizer`` (one that updates this model's parameters)."""
        optimizer.register_step_post_hook(partial(_changed_after_step, self))

    def version(self) -> tuple[int, ...]:
        """Changes whenever the parameters or buffers are written (:meth:`mark_changed`) or a tensor is replaced
        (``param.data = ...``, a move to another device: its storage's address changes). What :class:`StepLikelihood`
        checks at every step of the beliefs to stay in step with the model: a few microseconds (the tensors are listed
        once per revision; walking the module tree each time would cost ten times as much)."""
        if self._tensors is None:
            self._tensors = [*self.parameters(), *self.buffers()]
        return (self.revision, *(tensor.data_ptr() for tensor in self._tensors))

    @th.no_grad()
    def split_component(self, dead: int, source: int, noise: float = 0.05, generator: th.Generator | None = None) -> None:
        """Re-seed a starved component by splitting ``source`` in two along a random direction of its means: one
        half moves by ``+delta``, the other by ``-delta`` (``delta`` about ``noise`` of the parameters' scale); they
        share ``source``'s prior mass.

        Mixture fits starve components whose first fits were poor; a symmetric split gives each episode a reason to
        prefer one half (the side of ``delta`` it lies on), where a one-sided perturbation would be better or worse
        for all of them at once (split-and-merge EM).
        """
        for param in (self.decoder_weight, self.decoder_bias):
            delta = noise * th.randn(param[source].shape, generator=generator).to(param.device)
            delta *= param[source].abs().mean() + 1e-3
            param[dead] = param[source] + delta
            param[source] -= delta
        log_rates = self.count_log_rates
        if log_rates is not None:  # (has_counts) the rates split likewise, on the log scale
            delta = noise * th.randn(log_rates[source].shape, generator=generator).to(self.log_prior.device)
            log_rates[dead] = log_rates[source] + delta
            log_rates[source] -= delta
        prior = self.prior()
        prior[dead] = prior[source] = prior[source] / 2
        self.log_prior.copy_((prior / prior.sum()).log())
        self.mark_changed()


@njit(cache=True)
def _step_log_density(changes: np.ndarray, features: np.ndarray, next_features: np.ndarray, inv_std: np.ndarray,
                      constant: float, out: np.ndarray) -> None:  # pragma: no cover (compiled)
    """``out[b, k] = constant - |(next_features[b] - features[b] - changes[b, k]) * inv_std|^2 / 2`` for ``changes``
    ``(B, K * d_x)``: the Gaussian log-densities of :class:`StepLikelihood`, in one pass."""
    n, k = out.shape
    d = features.shape[1]
    for b in range(n):
        for j in range(k):
            total = 0.0
            for i in range(d):
                z = (np.float64(next_features[b, i]) - features[b, i] - changes[b, j * d + i]) * inv_std[i]
                total += z * z
            out[b, j] = constant - 0.5 * total


class StepLikelihood:
    """``log p(x_{t+1} | x_t, a_t, z = k)`` and ``log pi`` of a :class:`LatentModel`, lean, for the belief's one
    transition per step.

    The beliefs run the decoder on a few dozen rows per environment step; at that size torch's fixed cost per
    operation (some 15 operations with autograd's bookkeeping) outweighs the arithmetic. Here the
    three matrix products run through torch on a copy of the weights (the shared and per-component read-outs
    folded into one) and the rest in one compiled pass. The copy is
    refreshed whenever the model's :meth:`LatentModel.version` changes, so it always computes what
    :meth:`LatentModel.transition_log_likelihood` computes (float32, to rounding).

    :param model: the latent model
    """

    def __init__(self, model: LatentModel) -> None:
        self.model = model
        self._model_version: tuple[int, ...] | None = None

    def _refresh(self) -> None:
        model = self.model
        version = model.version()
        if version == self._model_version:
            return
        with th.no_grad():
            copy = lambda t: t.detach().to("cpu", th.float32).clone()  # noqa: E731
            self.trunk = [(copy(layer.weight).T.contiguous(), copy(layer.bias))
                          for layer in model.decoder_trunk if isinstance(layer, nn.Linear)]
            k, hidden, d_x = model.decoder_weight.shape
            # The shared read-out and every component's own, as one (hidden, K * d_x) product.
            weight = copy(model.decoder_weight) + copy(model.decoder_shared.weight).T[None]
            mask = model.transition_mask
            #: the features' factor in the means (1 each, 0 for a reading), None without readings
            self.mask = None if mask is None else mask.detach().cpu().numpy().astype(np.float32)
            if mask is not None:
                weight = weight * copy(mask)
            self.readout = weight.permute(1, 0, 2).reshape(hidden, k * d_x).contiguous()
            self.bias = (copy(model.decoder_bias) + copy(model.decoder_shared.bias)[None]).reshape(-1)
            log_std = model.log_std().detach().cpu().double()
            self.inv_std = (-log_std).exp().numpy()
            self.constant = -float(gaussian_log_normalizer(log_std))
            #: each feature's part of the constant (``constant = weighted_constant.sum()``), for tempered densities
            self.weighted_constant = -(log_std.numpy() + 0.5 * math.log(2 * math.pi))
            self.log_prior = model.log_prior.detach().cpu().double().numpy().copy()
            self.shape = (k, d_x)
            if model.count_log_rates is not None:  # (has_counts) the count log-likelihood's table: minus the rates, then
                log_rates = model.count_log_rates.detach().cpu().double()  # each channel's log-rates (K, channels, bins)
                table = th.cat([-log_rates.exp().sum(1, keepdim=True), log_rates], dim=1)  # (K, 1 + channels, bins)
                self.count_table = table.permute(1, 2, 0).contiguous().numpy()  # (1 + channels, bins, K)
        self._model_version = version

    def log_likelihood(self, features: np.ndarray, actions: np.ndarray, next_features: np.ndarray,
                       temperature: float = 1.0) -> np.ndarray:
        """``(B, K)`` float64 log-likelihoods of the transitions ``(features, actions) -> next_features``, tempered:
        ``temperature`` (``beta``) times the terms of the transition features, plus the terms of the readings (the
        layout's ``reading_features``, modelled exactly: never tempered)."""
        self._refresh()
        inv_std, constant = self.inv_std, self.constant
        if self.mask is not None and temperature != 1.0:  # (the weights folded into the deviations and the constant)
            weights = np.where(self.mask > 0, temperature, 1.0)
            inv_std, constant = inv_std * np.sqrt(weights), float(self.weighted_constant @ weights)
        # The products through torch, not numpy's ``@``: numpy's OpenBLAS starts worker threads for products of a
        # few dozen rows and they keep spinning between calls (a share of a second core, for no speed), where torch's
        # obey ``torch.set_num_threads`` as the networks do. One inference-mode
        # block for all of them: torch's fixed cost per call is most of their time at this size.
        with th.inference_mode():
            hidden = th.from_numpy(np.concatenate([features, actions], axis=1, dtype=np.float32))
            for weight, bias in self.trunk:
                hidden = th.tanh(th.addmm(bias, hidden, weight))
            changes = th.addmm(self.bias, hidden, self.readout).numpy()
        out = np.empty((len(features), self.shape[0]))
        features = np.asarray(features, dtype=np.float32)
        if self.mask is not None:  # (a reading's mean does not start from its last value)
            features = features * self.mask
        _step_log_density(changes, features, np.asarray(next_features, dtype=np.float32), inv_std, constant, out)
        if self.mask is None and temperature != 1.0:
            out *= temperature
        return out

    def count_log_likelihood(self, counter: CountEvidence, observations: np.ndarray, refresh: bool = True) -> np.ndarray:
        """``(B, K)`` float64 log-likelihoods of the reading counts of each observation ``(B, obs_dim)`` (what
        :meth:`LatentModel.count_log_likelihood` gives for the counts and exposures ``counter`` finds in them).

        :param counter: the observations' count evidence (the environment's plug-in's)
        :param refresh: check the model's version first (False: the caller has just done so, with nothing written
            to the model since)
        """
        if refresh:
            self._refresh()
        return counter.log_likelihood(observations, self.count_table)

    def prior(self, refresh: bool = True) -> np.ndarray:
        """``log pi`` ``(K,)``, float64.

        :param refresh: check the model's version first (False: the caller has just done so, with nothing written
            to the model since)
        """
        if refresh:
            self._refresh()
        return self.log_prior
