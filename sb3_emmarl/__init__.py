"""sb3-emmarl: latent-variable multi-agent reinforcement learning on Stable-Baselines3."""

from sb3_emmarl.common.callbacks import EvalCallback
from sb3_emmarl.common.evaluation import evaluate_policy
from sb3_emmarl.common.latent.callback import EMCallback
from sb3_emmarl.common.latent.evidence import register_evidence
from sb3_emmarl.common.latent.reserve_evidence import ReserveEvidence
from sb3_emmarl.common.latent.zone_evidence import ZoneEvidence
from sb3_emmarl.em_ddpg import EMDDPG
from sb3_emmarl.em_ppo import EMPPO
from sb3_emmarl.mappo import MAPPO
from sb3_emmarl.message_ppo import MessagePPO
from sb3_emmarl.oracle_ppo import OraclePPO
from sb3_emmarl.qmix import QMIX
from sb3_emmarl.vdn import VDN
from sb3_emmarl.vdn_em import EMVDN
from sb3_emmarl.version import __version__

# The package's evidence plug-ins of the latent model (common/latent/evidence.py), registered here, in the order
# evidence_of asks them (a user's plug-ins come after).
for _plugin in (ReserveEvidence, ZoneEvidence):
    register_evidence(_plugin)
del _plugin

__all__ = ["EMDDPG", "EMPPO", "EMVDN", "MAPPO", "QMIX", "VDN", "EMCallback", "EvalCallback", "MessagePPO", "OraclePPO",
           "__version__", "evaluate_policy"]
