from sb3_emmarl.common.latent.policies import LatentActorCriticPolicy

MlpPolicy = LatentActorCriticPolicy
