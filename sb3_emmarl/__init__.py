"""sb3-emmarl: latent-variable multi-agent reinforcement learning on Stable-Baselines3.

The algorithms and tools below are imported when first used (PEP 562), so that ``import sb3_emmarl`` and the
``emmarl`` command's help need no torch: ``from sb3_emmarl import EMPPO`` works as before.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from sb3_emmarl.version import __version__

#: Each public name and the module that defines it.
_EXPORTS = {
    "EvalCallback": "sb3_emmarl.common.callbacks", "evaluate_policy": "sb3_emmarl.common.evaluation",
    "EMCallback": "sb3_emmarl.common.latent.callback", "register_evidence": "sb3_emmarl.common.latent.evidence",
    "ReserveEvidence": "sb3_emmarl.common.latent.reserve_evidence", "ZoneEvidence": "sb3_emmarl.common.latent.zone_evidence",
    "EMDDPG": "sb3_emmarl.em_ddpg", "EMPPO": "sb3_emmarl.em_ppo", "MAPPO": "sb3_emmarl.mappo",
    "MessagePPO": "sb3_emmarl.message_ppo", "OraclePPO": "sb3_emmarl.oracle_ppo", "QMIX": "sb3_emmarl.qmix",
    "VDN": "sb3_emmarl.vdn", "EMVDN": "sb3_emmarl.vdn_em",
}

__all__ = ["EMDDPG", "EMPPO", "EMVDN", "MAPPO", "QMIX", "VDN", "EMCallback", "EvalCallback", "MessagePPO", "OraclePPO",
           "__version__", "evaluate_policy"]

if TYPE_CHECKING:  # (the type checker reads the names as the imports they are)
    from sb3_emmarl.common.callbacks import EvalCallback
    from sb3_emmarl.common.evaluation import evaluate_policy
    from sb3_emmarl.common.latent.callback import EMCallback
    from sb3_emmarl.common.latent.evidence import register_evidence as register_evidence
    from sb3_emmarl.common.latent.reserve_evidence import ReserveEvidence as ReserveEvidence
    from sb3_emmarl.common.latent.zone_evidence import ZoneEvidence as ZoneEvidence
    from sb3_emmarl.em_ddpg import EMDDPG
    from sb3_emmarl.em_ppo import EMPPO
    from sb3_emmarl.mappo import MAPPO
    from sb3_emmarl.message_ppo import MessagePPO
    from sb3_emmarl.oracle_ppo import OraclePPO
    from sb3_emmarl.qmix import QMIX
    from sb3_emmarl.vdn import VDN
    from sb3_emmarl.vdn_em import EMVDN


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'sb3_emmarl' has no attribute {name!r}")
    value = getattr(importlib.import_module(_EXPORTS[name]), name)
    globals()[name] = value  # (imported once)
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
