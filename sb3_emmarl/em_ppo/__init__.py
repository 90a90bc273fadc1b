from sb3_emmarl.em_ppo.em_ppo import EMPPO
from sb3_emmarl.em_ppo.policies import MlpPolicy

__all__ = ["EMPPO", "MlpPolicy"]
