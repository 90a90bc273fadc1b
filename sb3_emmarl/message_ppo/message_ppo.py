"""PPO over what teammates send: the graph-attention and transformer policies of the paper's table 6.

A thin PPO subclass, as :class:`~sb3_emmarl.oracle_ppo.OraclePPO` is, so that the zoo, ``evaluate_team`` and
``load`` give the model the environment it was trained on: every environment it gets is wrapped in a
:class:`~sb3_emmarl.common.messages.NeighbourMessageWrapper` (the messages of the teammates whose broadcasts
reached the UAV this step, nearest first), and its policy's features extractor is
:class:`~sb3_emmarl.common.extractors.GraphAttentionExtractor` (``extractor="gat"``) or
:class:`~sb3_emmarl.common.extractors.TransformerExtractor` (``"transformer"``). The policy stays decentralised: a
UAV reads its own observation and what it received. Python users can do the same with plain PPO:
``PPO("MlpPolicy", NeighbourMessageWrapper(venv), policy_kwargs=message_policy_kwargs(wrapped, "gat"))``.
"""

from __future__ import annotations

from typing import Any

from stable_baselines3 import PPO
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.appended.wrapping import WrapsObservations, ensure_wrapped
from sb3_emmarl.common.extractors import message_policy_kwargs
from sb3_emmarl.common.messages import NeighbourMessageWrapper
from sb3_emmarl.common.trust.validation import RULES


def wrap_with_messages(env: Any, max_messages: int, verbose: int = 0) -> VecEnv:
    """``env`` as a vector environment whose observations end with the neighbour messages (kept if already wrapped
    with as many slots)."""

    def mismatch(wrapper: NeighbourMessageWrapper) -> str | None:
        return None if wrapper.layout.n_slots == max_messages else (
            f"the environment's NeighbourMessageWrapper has {wrapper.layout.n_slots} slots, but "
            f"max_messages={max_messages}")

    return ensure_wrapped(env, NeighbourMessageWrapper, lambda venv: NeighbourMessageWrapper(venv, max_messages),
                          mismatch, verbose)


class MessagePPO(WrapsObservations, PPO):
    """PPO whose shared policy attends over the messages the UAV received (see the module docstring).

    :param policy: ``"MlpPolicy"`` (its features extractor is set from ``extractor``)
    :param env: the reserve's parameter-sharing vector environment (wrapped here)
    :param extractor: ``"gat"`` (graph attention over the neighbour tokens) or ``"transformer"`` (a transformer
        encoder over the UAV, its neighbours and patches of its window and maps)
    :param max_messages: neighbour slots (nearest first)
    :param extractor_kwargs: more arguments of the extractor (``features_dim``, ``n_heads``, ``n_rounds``...)
    :param args: PPO's positional arguments
    :param kwargs: PPO's keyword arguments (``policy_kwargs`` may add e.g. ``net_arch``)
    """

    def __init__(self, policy: str | type[ActorCriticPolicy], env: Any, *args: Any, extractor: str = "gat",
                 max_messages: int = 8, extractor_kwargs: dict[str, Any] | None = None, **kwargs: Any) -> None:
        self.extractor = RULES["extractor"]("extractor", extractor)
        self.max_messages = RULES["max_messages"]("max_messages", max_messages)
        if not isinstance(extractor_kwargs, (dict, type(None))):
            raise ValueError(f"extractor_kwargs must be a dict, got {extractor_kwargs!r}")
        self.extractor_kwargs = dict(extractor_kwargs or {})
        if env is not None and not isinstance(env, str):
            env = wrap_with_messages(env, self.max_messages, kwargs.get("verbose", 0))
            if kwargs.get("_init_setup_model", True):  # loading: the saved policy_kwargs hold the extractor
                kwargs["policy_kwargs"] = {**message_policy_kwargs(env, self.extractor, **self.extractor_kwargs),
                                           **(kwargs.get("policy_kwargs") or {})}
        super().__init__(policy, env, *args, **kwargs)

    def wrap_env(self, venv: VecEnv) -> VecEnv:
        """``venv`` with the neighbour messages appended to its observations (for evaluation and recording)."""
        return wrap_with_messages(venv, self.max_messages, self.verbose)

    @classmethod
    def _wrap_saved_env(cls, env: Any, data: dict[str, Any]) -> VecEnv:
        """The neighbour messages the model was trained with."""
        return wrap_with_messages(env, int(data.get("max_messages", 8)))

