"""sb3-emmarl: latent-variable multi-agent reinforcement learning on Stable-Baselines3."""

# The environments' evidence plug-ins of the latent model (common/latent/evidence.py), registered on import.
from sb3_emmarl.common import reserve_evidence, zone_evidence  # noqa: F401
from sb3_emmarl.common.callbacks import EvalCallback
from sb3_emmarl.common.evaluation import evaluate_policy
from sb3_emmarl.common.latent.callback import EMCallback
from sb3_emmarl.em_ddpg import EMDDPG
from sb3_emmarl.em_ppo import EMPPO
from sb3_emmarl.mappo import MAPPO
from sb3_emmarl.message_ppo import MessagePPO
from sb3_emmarl.oracle_ppo import OraclePPO
from sb3_emmarl.qmix import QMIX
from sb3_emmarl.vdn import VDN
from sb3_emmarl.vdn_em import EMVDN
from sb3_emmarl.version import __version__

__all__ = ["EMDDPG", "EMPPO", "EMVDN", "MAPPO", "QMIX", "VDN", "EMCallback", "EvalCallback", "MessagePPO", "OraclePPO",
           "__version__", "evaluate_policy"]
