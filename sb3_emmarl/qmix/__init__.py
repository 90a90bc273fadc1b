from sb3_emmarl.qmix.buffers import JointReplayBuffer, JointReplaySamples
from sb3_emmarl.qmix.mixers import QMixer, VDNMixer
from sb3_emmarl.qmix.policies import MlpPolicy, QMIXPolicy, ValueDecompositionPolicy, VDNPolicy
from sb3_emmarl.qmix.qmix import QMIX

__all__ = ["QMIX", "JointReplayBuffer", "JointReplaySamples", "MlpPolicy", "QMIXPolicy", "QMixer",
           "VDNMixer", "VDNPolicy", "ValueDecompositionPolicy"]
