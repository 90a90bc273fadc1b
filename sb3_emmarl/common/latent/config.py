"""The EM algorithms' latent settings as one record, validated once.

EM-PPO, EM-DDPG and VDN+EM take the same latent arguments (SB3's style: keyword parameters of the constructor, each
documented there); each constructor gathers them into a :class:`LatentConfig`, which checks every field by its rule in
:data:`~sb3_emmarl.common.validation.RULES` (the one place the rules live) and how the fields fit together, and
:meth:`~sb3_emmarl.common.latent.algorithm.LatentAlgorithmMixin._init_latent` takes it whole. The model keeps each
field as an attribute of the same name (saved with it as SB3 saves constructor arguments, so models saved before the
record existed load unchanged); ``model.latent_config`` gives the record back.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from sb3_emmarl.common.latent.counts import check_factors
from sb3_emmarl.common.validation import RULES


@dataclass(frozen=True)
class LatentConfig:
    """The latent settings of an EM algorithm (see EM-PPO's constructor for what each does; defaults are EM-PPO's).

    :raise ValueError: naming the field, its value and what is allowed
    """

    n_components: int = 4
    decoder_hidden: tuple[int, ...] = (64, 64)
    likelihood_temperature: float = 1.0
    fusion: bool | str = True
    estimator: str = "enumerate"
    team_pooling: bool = False
    reading_counts: bool = True
    count_factors: tuple[int, int] | None = None
    e_step_interval: int = 1
    belief_input: str = "probabilities"
    e_step_kwargs: dict[str, Any] | None = None
    use_latent: bool = True
    freeze_e_step: bool = False
    freeze_m_step: bool = False

    def __post_init__(self) -> None:
        for field in fields(self):
            value = RULES[field.name](field.name, getattr(self, field.name))
            if field.name == "decoder_hidden":
                value = tuple(value)
            elif field.name == "likelihood_temperature":
                value = float(value)
            elif field.type == "bool":
                value = bool(value)
            object.__setattr__(self, field.name, value)
        object.__setattr__(self, "count_factors", check_factors(self.count_factors, self.n_components))

    @classmethod
    def of(cls, model: Any) -> LatentConfig:
        """The settings a model holds as attributes (what :meth:`_init_latent` set, or a loaded model's data)."""
        return cls(**{field.name: getattr(model, field.name) for field in fields(cls)})

    @classmethod
    def from_arguments(cls, arguments: dict[str, Any]) -> LatentConfig:
        """The record of a constructor's arguments (``LatentConfig.from_arguments(locals())`` in EM-PPO's, EM-DDPG's
        and VDN+EM's ``__init__``, whose latent parameters are named as the fields): every field is taken from
        ``arguments``, so the three constructors gather their latent settings in one line each."""
        return cls(**{field.name: arguments[field.name] for field in fields(cls)})

    def names(self) -> tuple[str, ...]:
        """The fields' names, in order."""
        return tuple(field.name for field in fields(self))
