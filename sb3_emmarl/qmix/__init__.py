from sb3_emmarl.qmix.buffers import (
    JointReplayBuffer,
    JointReplaySamples,
    JointSequenceSamples,
    RecurrentJointReplayBuffer,
)
from sb3_emmarl.qmix.mixers import QMixer, VDNMixer
from sb3_emmarl.qmix.policies import (
    MlpPolicy,
    QMIXPolicy,
    RecurrentAgentQNetwork,
    ValueDecompositionPolicy,
    VDNPolicy,
)
from sb3_emmarl.qmix.qmix import QMIX

__all__ = ["QMIX", "JointReplayBuffer", "JointReplaySamples", "JointSequenceSamples", "MlpPolicy", "QMIXPolicy",
           "QMixer", "RecurrentAgentQNetwork", "RecurrentJointReplayBuffer", "VDNMixer", "VDNPolicy",
           "ValueDecompositionPolicy"]
