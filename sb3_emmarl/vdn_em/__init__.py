from sb3_emmarl.vdn_em.policies import LatentVDNPolicy, MlpPolicy
from sb3_emmarl.vdn_em.vdn_em import EMVDN

__all__ = ["EMVDN", "LatentVDNPolicy", "MlpPolicy"]
