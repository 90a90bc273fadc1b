"""Oracle PPO: parameter-shared PPO whose observation carries the true hidden mode."""

from __future__ import annotations

from typing import Any, ClassVar

from stable_baselines3 import PPO
from stable_baselines3.common.policies import ActorCriticPolicy, BasePolicy
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.appended.conditioning import ConditionedPolicyMixin, ContextActorCriticPolicy
from sb3_emmarl.common.appended.initialization import hold_tail_weights_at_zero, zero_tail_weights
from sb3_emmarl.common.appended.wrapping import WrapsObservations, find_wrapper
from sb3_emmarl.common.mode_aware import ModeObservationWrapper, wrap_with_mode
from sb3_emmarl.common.trust.validation import RULES
from wildlife_reserve.reserve.modes import N_MODES


class OraclePPO(WrapsObservations, PPO):
    """PPO that is told the episode's true hidden mode: the upper bound every latent method is measured against.

    The environment (and any environment given to ``load``, ``set_env`` or :meth:`wrap_env`) is wrapped in a
    :class:`~sb3_emmarl.common.mode_aware.ModeObservationWrapper`, which appends a one-hot of the mode from the
    reserve's infos. No UAV can observe the mode, so this is a reference, not a deployable team: the gap
    between it and plain PPO is what inferring the mode can win at most (``benchmarks/mode_value.py``).
    Unlike the other algorithms it cannot act through ``predict`` on the plain environment's observations
    alone; evaluate it on ``model.wrap_env(env)`` (``evaluate_team`` does).

    The weights with which the first layers read the one-hot start at zero (``zero_mode_weights``): the
    networks start as plain PPO's, and learn what the mode is worth from there (see
    :mod:`sb3_emmarl.common.appended.initialization` for why).

    Which networks read the mode is ``mode_input``: both (the default), or only the policy (the critic's weights on
    the one-hot stay at zero: the mode can change what the team does, not what it expects), or only the value (the
    policy acts as PPO's does, with a critic that knows the mode). The two halves tell apart what the mode does for
    the actions and what it does for the advantages.

    With ``random_label=True`` the observation carries, instead of the mode, a label drawn at random per episode
    (the same one-hot form, constant over the episode, shared by a reserve's UAVs, independent of the mode): a control
    that pays whatever such an input costs PPO to learn with, and learns nothing from it. Told PPO against this control
    is what the mode's information is worth apart from that cost (``benchmarks/mode_value.py``).

    :param zero_mode_weights: start the weights that read the mode at zero (with SB3's ``FlattenExtractor``;
        another features extractor reads the one-hot as it reads the rest); False keeps SB3's orthogonal
        initialisation for them
    :param mode_input: ``"both"``, ``"policy"`` or ``"value"``: the networks whose first layers read the one-hot; the
        other network's weights on it are held at zero (their gradient is masked); needs SB3's ``FlattenExtractor``
    :param random_label: append a random label per episode instead of the mode (the control above); saved with the
        model, so that ``load`` and :meth:`wrap_env` give it random labels again

    How the networks read the one-hot is ``policy_kwargs["belief_conditioning"]`` (``"concat"``, SB3's networks, the
    default; ``"mixture"``, an action head and a value head per mode; ``"film"``: see
    :mod:`sb3_emmarl.common.appended.conditioning`), with ``"MlpPolicy"``, which is
    :class:`~sb3_emmarl.common.appended.conditioning.ContextActorCriticPolicy` here.

    Every other argument is PPO's (see :class:`stable_baselines3.PPO`).
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {**PPO.policy_aliases, "MlpPolicy": ContextActorCriticPolicy}

    def __init__(self, policy: str | type[ActorCriticPolicy], env: Any, *args: Any, zero_mode_weights: bool = True,
                 mode_input: str = "both", random_label: bool = False, **kwargs: Any) -> None:
        self.zero_mode_weights = RULES["zero_mode_weights"]("zero_mode_weights", zero_mode_weights)
        self.mode_input = RULES["mode_input"]("mode_input", mode_input)
        self.random_label = RULES["random_label"]("random_label", random_label)
        loading = not kwargs.get("_init_setup_model", True)  # SB3's load: env is wrapped as the saved model asks
        told = loading and find_wrapper(env, ModeObservationWrapper) is not None
        if env is not None and not isinstance(env, str) and not told:
            env = wrap_with_mode(env, kwargs.get("verbose", 0), self.random_label)
        wrapper = find_wrapper(env, ModeObservationWrapper) if isinstance(env, VecEnv) else None
        policy_class = self.policy_aliases.get(policy, policy) if isinstance(policy, str) else policy
        if wrapper is not None and isinstance(policy_class, type) and issubclass(policy_class, ConditionedPolicyMixin):
            kwargs["policy_kwargs"] = {**(kwargs.get("policy_kwargs") or {}), "context_dim": wrapper.n_modes}
        super().__init__(policy, env, *args, **kwargs)

    def _setup_model(self) -> None:
        super()._setup_model()
        wrapper = find_wrapper(self.env, ModeObservationWrapper) if self.env is not None else None
        n_modes = wrapper.n_modes if wrapper is not None else N_MODES
        if self.zero_mode_weights:
            zero_tail_weights(self.policy, n_modes)
        if self.mode_input != "both":
            blind = "value" if self.mode_input == "policy" else "policy"
            if not hold_tail_weights_at_zero(self.policy, n_modes, blind):
                raise ValueError(f"mode_input={self.mode_input!r} needs SB3's FlattenExtractor and belief_conditioning "
                                 f"'concat' (the first layers must read the one-hot directly), got "
                                 f"{type(self.policy.features_extractor).__name__} and "
                                 f"{getattr(self.policy, 'belief_conditioning', 'concat')!r}")

    def wrap_env(self, venv: VecEnv) -> VecEnv:
        """``venv`` with the true mode (or the random label) appended to its observations (for evaluation and
        recording)."""
        return wrap_with_mode(venv, self.verbose, self.random_label)

    @classmethod
    def _wrap_saved_env(cls, env: Any, data: dict[str, Any]) -> VecEnv:
        """The mode (or the saved model's random label) appended to the observations."""
        return wrap_with_mode(env, random_labels=bool(data.get("random_label", False)))
