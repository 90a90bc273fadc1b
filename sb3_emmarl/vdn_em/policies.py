"""The policy of VDN+EM: VDN's shared agent Q-network reading the observation and the belief over the hidden mode."""

from __future__ import annotations

from sb3_emmarl.common.latent.policies import LatentPolicyMixin
from sb3_emmarl.qmix.policies import VDNPolicy


class LatentVDNPolicy(LatentPolicyMixin, VDNPolicy):
    """:class:`~sb3_emmarl.qmix.policies.VDNPolicy` whose agent network (and its target) sees the belief (VDN+EM).

    Takes ``VDNPolicy``'s arguments plus ``latent_layout`` (set by the algorithm), ``use_latent`` and ``belief_input``;
    the latent model is the policy's (saved with it) and outside its optimizer, as in EM-PPO and EM-DDPG.
    """


MlpPolicy = LatentVDNPolicy
