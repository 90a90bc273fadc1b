from sb3_emmarl.em_ddpg.em_ddpg import EMDDPG
from sb3_emmarl.em_ddpg.policies import MlpPolicy

__all__ = ["EMDDPG", "MlpPolicy"]
