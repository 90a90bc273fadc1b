from sb3_emmarl.mappo.mappo import MAPPO
from sb3_emmarl.mappo.policies import MAPPOPolicy, MlpPolicy, ValueNorm
from sb3_emmarl.mappo.wrappers import GlobalStateWrapper, StateLayout

__all__ = ["MAPPO", "GlobalStateWrapper", "MAPPOPolicy", "MlpPolicy", "StateLayout", "ValueNorm"]
