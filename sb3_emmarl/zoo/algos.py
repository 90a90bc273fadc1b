"""Which algorithms the zoo trains on the reserve, and in which view.

rl_zoo3 takes new algorithms by insertion into ``rl_zoo3.ALGOS`` (and, for ``-optimize``, into its
``HYPERPARAMS_SAMPLER`` / ``HYPERPARAMS_CONVERTER``); :func:`register_algorithms` does that once.
"""

from __future__ import annotations

from sb3_contrib import RecurrentPPO
from stable_baselines3 import A2C, DDPG, DQN, PPO, TD3
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_emmarl.em_ddpg import EMDDPG
from sb3_emmarl.em_ppo import EMPPO
from sb3_emmarl.mappo import MAPPO
from sb3_emmarl.message_ppo import MessagePPO
from sb3_emmarl.oracle_ppo import OraclePPO
from sb3_emmarl.qmix import QMIX
from sb3_emmarl.vdn import VDN
from sb3_emmarl.vdn_em import EMVDN

#: Algorithms trained with one policy shared by all UAVs (the parameter-sharing vector environment).
SHARED_ALGOS: dict[str, type[BaseAlgorithm]] = {
    "ppo": PPO,  # decentralized PPO
    "a2c": A2C,
    "dqn": DQN,  # the paper's Q-learning
    "ddpg": DDPG,  # continuous action mode
    "td3": TD3,  # continuous action mode
    "ppo_lstm": RecurrentPPO,
    "em_ppo": EMPPO,  # the paper's method, with PPO as the M-step
    "em_ddpg": EMDDPG,  # the paper's method, with DDPG as the M-step (continuous action mode)
    "oracle_ppo": OraclePPO,  # PPO told the true hidden mode: the upper bound of every latent method
    "mappo": MAPPO,  # PPO whose critic reads the global state (MAPPO)
    "qmix": QMIX,  # shared agent Q-network, monotonic mixing conditioned on the global state
    "vdn": VDN,  # shared agent Q-network, team value the sum of the agents'
    "vdn_em": EMVDN,  # the paper's VDN+EM: VDN whose agents see the EM belief
    "ppo_gat": MessagePPO,  # PPO with graph attention over the messages the UAV received (table 6)
    "ppo_transformer": MessagePPO,  # PPO with a transformer over the UAV, its messages and its window (table 6)
}
#: Algorithms trained on the centralised view (global state in, joint action out).
CENTRALIZED_ALGOS: dict[str, type[BaseAlgorithm]] = {
    "cppo": PPO,  # Centralized PPO
}
ZOO_ALGOS: dict[str, type[BaseAlgorithm]] = {**SHARED_ALGOS, **CENTRALIZED_ALGOS}
#: The EM algorithms (they add their belief wrapper themselves; the zoo logs their latent metrics).
LATENT_ALGOS = ("em_ppo", "em_ddpg", "vdn_em")
#: Algorithms that read the environment's global state (the zoo builds their environment with it).
STATE_ALGOS = ("mappo", "qmix")
#: Algorithms trained with another algorithm's hyperparameter file (the same settings by construction).
SHARED_HYPERPARAMS: dict[str, str] = {"oracle_ppo": "ppo"}


def register_algorithms() -> None:
    """Make rl_zoo3 know every algorithm of :data:`ZOO_ALGOS` (idempotent)."""
    import rl_zoo3
    from rl_zoo3 import hyperparams_opt

    for name, algo in ZOO_ALGOS.items():
        rl_zoo3.ALGOS.setdefault(name, algo)
    for name, like in (("cppo", "ppo"), ("em_ppo", "ppo"), ("em_ddpg", "ddpg"), ("oracle_ppo", "ppo"), ("mappo", "ppo"),
                       ("qmix", "dqn"), ("vdn", "dqn"), ("vdn_em", "dqn"),
                       ("ppo_gat", "ppo"), ("ppo_transformer", "ppo")):
        hyperparams_opt.HYPERPARAMS_SAMPLER.setdefault(name, hyperparams_opt.HYPERPARAMS_SAMPLER[like])
        hyperparams_opt.HYPERPARAMS_CONVERTER.setdefault(name, hyperparams_opt.HYPERPARAMS_CONVERTER[like])
