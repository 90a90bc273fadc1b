"""Where the parts of a belief-augmented observation sit, and the latent model's sizes: one source of truth."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from sb3_emmarl.common.trust.validation import LATENT_RULES


@dataclass(frozen=True)
class LatentLayout:
    """The sizes every part of the latent machinery reads (all ints, saved with the model's policy).

    An augmented observation is ``[observation (obs_dim), belief (n_components)]``: the environment's own
    observation followed by the agent's belief ``q(z | o_{1:t}, a_{1:t-1})`` over the latent components.

    :param obs_dim: size of the environment's (flat) observation
    :param feature_dim: ``d_x``, compact features of one observation that the decoder models
    :param action_dim: size of the encoded action (one-hot size for discrete actions)
    :param n_components: ``K``, components of the categorical latent variable
    :param decoder_hidden: hidden layer sizes of the decoder's shared trunk
    :param count_channels: channels of the count model (:mod:`~sb3_emmarl.common.latent.counts`); 0 with
        ``count_bins`` 0 when there is none (the environment's evidence plug-in counts nothing, or ``reading_counts``
        is off)
    :param count_bins: bins per channel of the count model
    :param reading_features: the indices of the features that are *readings*: read afresh at each step and, given the
        mode, independent of everything before (ZonePatrol's zone and visibility readings); the decoder models each as
        a Gaussian whose mean depends on the component alone, not on ``(x_t, a_t)`` (the environment's evidence
        plug-in names them: :attr:`~sb3_emmarl.common.latent.evidence.LatentEvidence.readings`); empty: every feature
        is modelled as a transition
    """

    obs_dim: int
    feature_dim: int
    action_dim: int
    n_components: int
    decoder_hidden: tuple[int, ...] = field(default=(64, 64))
    count_channels: int = 0
    count_bins: int = 0
    reading_features: tuple[int, ...] = field(default=())

    def __post_init__(self) -> None:
        LATENT_RULES["n_components"]("n_components", self.n_components)
        for name in ("obs_dim", "feature_dim", "action_dim"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}")
        for name in ("count_channels", "count_bins"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be an int >= 0, got {value!r}")
        if (self.count_channels == 0) != (self.count_bins == 0):
            raise ValueError(f"count_channels and count_bins must both be 0 (no count model) or both >= 1, got "
                             f"{self.count_channels} and {self.count_bins}")
        hidden = LATENT_RULES["decoder_hidden"]("decoder_hidden", self.decoder_hidden)
        object.__setattr__(self, "decoder_hidden", tuple(hidden))
        readings = self.reading_features
        if isinstance(readings, (str, bytes)) or not hasattr(readings, "__iter__") or not all(
                isinstance(i, int) and not isinstance(i, bool) and 0 <= i < self.feature_dim for i in readings) \
                or len(set(readings)) != len(tuple(readings)):
            raise ValueError(f"reading_features must be distinct feature indices in [0, {self.feature_dim - 1}], "
                             f"got {readings!r}")
        object.__setattr__(self, "reading_features", tuple(sorted(readings)))

    @property
    def total_dim(self) -> int:
        """Size of an augmented observation."""
        return self.obs_dim + self.n_components

    def split(self, observations: Any) -> tuple[Any, Any]:
        """Split augmented observations ``(..., total_dim)`` (numpy or torch) into the observation and the belief."""
        return observations[..., : self.obs_dim], observations[..., self.obs_dim:]

    def to_dict(self) -> dict[str, Any]:
        """Plain values for ``policy_kwargs`` (saved in the model's zip)."""
        data = {**asdict(self), "decoder_hidden": list(self.decoder_hidden), "reading_features": list(self.reading_features)}
        if not self.reading_features:  # (as layouts were saved before readings existed)
            del data["reading_features"]
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LatentLayout:
        return cls(**{**data, "decoder_hidden": tuple(data.get("decoder_hidden", (64, 64))),
                      "reading_features": tuple(data.get("reading_features", ()))})
