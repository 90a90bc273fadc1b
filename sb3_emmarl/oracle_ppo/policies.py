from stable_baselines3.common.policies import ActorCriticPolicy

MlpPolicy = ActorCriticPolicy
