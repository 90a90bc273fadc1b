"""The EM algorithms' latent settings: one record, one surface (``latent_kwargs``), validated once.

EM-PPO, EM-DDPG, VDN+EM and :class:`~sb3_emmarl.common.latent.callback.EMCallback` take their latent settings as one
argument, ``latent_kwargs`` (a :class:`LatentConfig` or a dict of its fields), as SB3 takes a policy's settings as
``policy_kwargs``. Each algorithm's own defaults are its class attribute ``latent_defaults``; :meth:`LatentConfig.updated`
lays the given fields over them (``e_step_kwargs`` key by key) and fills the E-step's defaults in. The record checks
every field by its rule in :data:`~sb3_emmarl.common.trust.validation.LATENT_RULES` (the one place the rules live)
and how the fields fit together. The model keeps it whole as ``model.latent_config``; what it saves is the record's fields
(``model.latent_kwargs``, plain data, as SB3 saves ``policy_kwargs``), and a model saved before the record existed
(its settings as attributes of their own) loads through :func:`upgrade_saved_settings`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from sb3_emmarl.common.latent.counts import check_factors
from sb3_emmarl.common.trust.validation import LATENT_RULES

#: Defaults of the E-step: the arguments of :class:`~sb3_emmarl.common.latent.em.EStep` that ``e_step_kwargs`` may
#: override (``estimator``, ``likelihood_temperature`` and ``seed`` come from the algorithm).
E_STEP_DEFAULTS: dict[str, Any] = {"learning_rate": 1e-3, "n_epochs": 5, "batch_size": 256, "window": 2,
                                   "max_transitions": 16384, "temperature": 1.0, "min_temperature": 0.1,
                                   "anneal_rate": 0.05, "starved_share": 0.1, "starved_patience": 1}


@dataclass(frozen=True)
class LatentConfig:
    """The latent settings of an EM algorithm (the defaults are EM-PPO's).

    :param n_components: ``K``, components of the latent variable
    :param decoder_hidden: hidden layer sizes of the transition models' shared trunk
    :param likelihood_temperature: ``beta``, the factor on every transition's log-likelihood in the beliefs and the
        responsibilities (below 1 tempers an overconfident decoder); the terms of the environment's readings (its
        evidence plug-in's ``readings``, modelled exactly) are not tempered
    :param fusion: beliefs combine the evidence of the teammates heard from, each counted once, newest version only
        (True: decentralised, along the environment's ``infos[i]["heard_from"]`` links; ``"team"``: every teammate's at
        every step, centralised inference, an ablation; False: each UAV's own)
    :param estimator: the E-step's estimator of the expected log-likelihood, ``"enumerate"`` (exact over ``K``) or
        ``"gumbel"`` (annealed Gumbel-softmax samples, as in the paper)
    :param team_pooling: in the E-step, the agents of one environment copy share one episode posterior (centralised
        training; execution stays decentralised)
    :param reading_counts: add the count model (``counts.py``) to the latent model when the environment's evidence
        plug-in counts readings (the reserve's: where signs, leopards and poachers were read); ignored elsewhere
    :param count_factors: ``(F1, F2)`` with ``F1 * F2 = n_components``: the count model's rates factor as where
        readings are made (by the first factor) x how far from the UAV (by the second); on the reserve ``(4, 2)``
        matches its modes (poacher strategy x weather, ``em_ppo.yml``); None: every component's every bin its own
    :param e_step_interval: between E-steps: rollouts (EM-PPO) or ``train()`` calls (EM-DDPG, VDN+EM); every rollout's
        transitions are kept
    :param e_step_every: agent-steps (``num_timesteps``, every copy and agent counted) between E-steps, whatever
        ``n_steps`` is. EM-PPO runs the E-step during the rollout, on the transitions collected since the last one, so
        that the belief is informed before the first policy update (None: every ``e_step_interval`` rollouts, at the
        rollout's end; give one of the two); :class:`~sb3_emmarl.common.latent.callback.EMCallback` at the first
        rollout end that many agent-steps after the last E-step (2000 by default); EM-DDPG and VDN+EM count
        ``e_step_interval`` ``train()`` calls instead
    :param belief_input: how the networks read the belief: ``"probabilities"`` as they are, ``"map"`` the one-hot of
        the most likely component (the form of a told mode), ``"both"`` the one-hot after the probabilities
        (docs/em.md, "Reading the belief")
    :param e_step_kwargs: overrides of :data:`E_STEP_DEFAULTS` (``window`` counts what ``e_step_interval`` counts;
        with ``e_step_every``, the parts handed to the E-step: each E-step's, and a rollout's remainder)
    :param use_latent: False is the no-latent ablation (same networks without the belief input, no E-step)
    :param freeze_e_step: ablation: the transition models and the prior keep their initial values (the belief is
        still computed, from an unfitted model)
    :param freeze_m_step: ablation: the policy's networks never change (the paper's "disabling the M-step")
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
    e_step_every: int | None = None
    belief_input: str = "probabilities"
    e_step_kwargs: dict[str, Any] | None = None
    use_latent: bool = True
    freeze_e_step: bool = False
    freeze_m_step: bool = False

    def __post_init__(self) -> None:
        for field in fields(self):
            value = LATENT_RULES[field.name](field.name, getattr(self, field.name))
            if field.name == "decoder_hidden":
                value = tuple(value)
            elif field.name == "likelihood_temperature":
                value = float(value)
            elif field.type == "bool":
                value = bool(value)
            object.__setattr__(self, field.name, value)
        object.__setattr__(self, "count_factors", check_factors(self.count_factors, self.n_components))
        if self.e_step_every is not None and self.e_step_interval != 1:
            raise ValueError(f"give one E-step schedule: e_step_every={self.e_step_every} (agent-steps) or "
                             f"e_step_interval={self.e_step_interval} (rollouts or train() calls), not both")

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The fields' names, in order."""
        return tuple(field.name for field in fields(cls))

    def updated(self, changes: LatentConfig | Mapping[str, Any] | None) -> LatentConfig:
        """These settings with ``changes`` laid over them (``e_step_kwargs`` key by key) and the E-step's defaults
        (:data:`E_STEP_DEFAULTS`) filled in: what an algorithm keeps of its ``latent_kwargs``.

        :param changes: a record (all its fields count) or a mapping of some fields
        :raise ValueError: naming an unknown field and the allowed ones, or a field's bad value
        """
        given = dict(check_latent_kwargs(changes))
        e_step_changes = LATENT_RULES["e_step_kwargs"]("e_step_kwargs", given.pop("e_step_kwargs", None))
        e_step_kwargs = {**E_STEP_DEFAULTS, **(self.e_step_kwargs or {}), **e_step_changes}
        return replace(self, **given, e_step_kwargs=e_step_kwargs)

    def to_dict(self) -> dict[str, Any]:
        """The fields as plain data (tuples as lists, as SB3's JSON would give them back)."""
        return {name: list(value) if isinstance(value, tuple) else value for name, value in asdict(self).items()}


def check_latent_kwargs(value: Any) -> Mapping[str, Any]:
    """``latent_kwargs`` as a mapping of :class:`LatentConfig`'s fields (None: none).

    :raise ValueError: naming ``latent_kwargs``, what it got and what is allowed
    """
    if value is None:
        return {}
    if isinstance(value, LatentConfig):
        return asdict(value)
    if not isinstance(value, Mapping):
        raise ValueError(f"latent_kwargs must be a LatentConfig or a dict of its fields, got {value!r}")
    unknown = sorted(set(value) - set(LatentConfig.names()), key=str)
    if unknown:
        raise ValueError(f"latent_kwargs keys must be among {list(LatentConfig.names())}, got {unknown}")
    return value


def reject_flat_latent_settings(owner: str, kwargs: Mapping[str, Any]) -> None:
    """Name the latent settings given as arguments of their own (as constructors took them before ``latent_kwargs``)
    and where they go now.

    :param owner: the class whose constructor got them
    :raise TypeError: as Python does for an unexpected keyword, saying to pass them in ``latent_kwargs``
    """
    flat = [name for name in LatentConfig.names() if name in kwargs]
    if flat:
        example = ", ".join(f"{name}={kwargs[name]!r}" for name in flat)
        raise TypeError(f"{owner} takes its latent settings {flat} in latent_kwargs: latent_kwargs=dict({example})")


def lift_flat_settings(mapping: Mapping[str, Any]) -> dict[str, Any]:
    """``mapping`` (a saved run's hyperparameters, a saved callback's arguments) with the latent settings written at
    its top level, as before ``latent_kwargs``, moved under ``latent_kwargs`` (beneath the fields already there); a
    mapping without them comes back as it is.

    :param mapping: the saved settings
    """
    flat = {name: mapping[name] for name in LatentConfig.names() if name in mapping}
    if not flat:
        return dict(mapping)
    rest = {key: value for key, value in mapping.items() if key not in flat}
    return {**rest, "latent_kwargs": {**flat, **(mapping.get("latent_kwargs") or {})}}


def upgrade_saved_settings(data: dict[str, Any]) -> dict[str, Any]:
    """A model's saved data from before ``latent_kwargs`` (its latent settings as attributes of their own, the latent
    layout as ``policy_kwargs["latent_kwargs"]``, the evidence plug-in's specification as ``feature_spec``) in today's
    form (``latent_kwargs``; the layout as ``policy_kwargs["latent_layout"]``; ``evidence_spec``); today's data is
    returned unchanged.

    :param data: the attributes SB3 saved (changed in place and returned)
    """
    if "feature_spec" in data:  # (the evidence plug-in's specification, named for its features before)
        data["evidence_spec"] = data.pop("feature_spec")
    policy_kwargs = data.get("policy_kwargs")
    if isinstance(policy_kwargs, dict) and "latent_kwargs" in policy_kwargs:
        policy_kwargs["latent_layout"] = policy_kwargs.pop("latent_kwargs")
    flat = {name: data.pop(name) for name in LatentConfig.names() if name in data}
    if flat:  # (today's models keep no setting as an attribute of its own)
        layout = (policy_kwargs or {}).get("latent_layout") or {}
        for name in ("n_components", "decoder_hidden"):
            if name in layout:
                flat[name] = layout[name]
        data["latent_kwargs"] = flat
    return data
