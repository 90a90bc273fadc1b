from sb3_emmarl.common.latent.policies import LatentTD3Policy

MlpPolicy = LatentTD3Policy
