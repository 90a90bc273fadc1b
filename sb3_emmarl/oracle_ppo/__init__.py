from sb3_emmarl.oracle_ppo.oracle_ppo import OraclePPO
from sb3_emmarl.oracle_ppo.policies import MlpPolicy

__all__ = ["MlpPolicy", "OraclePPO"]
