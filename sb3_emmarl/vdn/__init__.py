from sb3_emmarl.qmix.policies import VDNPolicy
from sb3_emmarl.vdn.vdn import VDN

MlpPolicy = VDNPolicy

__all__ = ["VDN", "MlpPolicy", "VDNPolicy"]
