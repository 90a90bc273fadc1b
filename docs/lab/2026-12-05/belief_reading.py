"""A one-off study (2026-12-05, sb3-emmarl 0.18.9 -> 0.19.0): does EM-PPO read its learned belief as fast as a told
mode or the exact posterior put in the belief's place?

EM-PPO trains on ``ModeGoalEnv`` (default arguments unless ``--kwargs`` says otherwise) with its belief wrapper's
output either as it is (``learned``), replaced by the one-hot of the true mode (``told``), or by the exact Bayes
posterior of the cues seen so far (``bayes``: the cue names the mode's corner with probability 0.625, each other
corner 0.125). The return is SB3's ``evaluate_policy`` (50 episodes from seed ``100_000 + seed``, deterministic
actions) at each fifth of the budget, on the belief the run trained with. The replacement patches the wrapper's
``reset`` and ``step_wait`` in this process only.

Example: ``python docs/lab/2026-12-05/belief_reading.py --belief bayes --seed 0 --kwargs '{"n_epochs": 5}'``
"""

import argparse
import json

import numpy as np
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_emmarl import EMPPO
from sb3_emmarl.common.latent import belief
from sb3_emmarl.common.mode_tasks import ModeGoalEnv

#: log P(cue = c | mode = m), rows c, columns m (ModeGoalEnv's defaults: cue_accuracy 0.5, 4 corners)
CUE_LOG_LIKELIHOOD = np.log(np.where(np.eye(4, dtype=bool), 0.5 + 0.5 / 4, 0.5 / 4))


def replace_beliefs(kind: str) -> None:
    step_wait, reset = belief.BeliefWrapper.step_wait, belief.BeliefWrapper.reset

    def write(wrapper, obs):
        if kind == "told":
            obs[:, -4:] = np.eye(4, dtype=np.float32)[wrapper.venv.get_attr("mode")]
        else:
            log_p = wrapper.log_posterior - wrapper.log_posterior.max(1, keepdims=True)
            obs[:, -4:] = (np.exp(log_p) / np.exp(log_p).sum(1, keepdims=True)).astype(np.float32)
        return obs

    def new_reset(wrapper):
        obs = reset(wrapper)
        wrapper.log_posterior = CUE_LOG_LIKELIHOOD[obs[:, 2:6].argmax(1)].copy()
        return write(wrapper, obs)

    def new_step_wait(wrapper):
        obs, rewards, dones, infos = step_wait(wrapper)
        wrapper.log_posterior[dones] = 0.0
        wrapper.log_posterior += CUE_LOG_LIKELIHOOD[obs[:, 2:6].argmax(1)]
        return write(wrapper, obs), rewards, dones, infos

    belief.BeliefWrapper.reset, belief.BeliefWrapper.step_wait = new_reset, new_step_wait


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--belief", choices=["learned", "told", "bayes"], default="learned")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("-n", type=int, default=150_000)
    parser.add_argument("--kwargs", type=json.loads, default={}, help="EMPPO arguments, as JSON")
    args = parser.parse_args()
    th.set_num_threads(1)
    if args.belief != "learned":
        replace_beliefs(args.belief)
    model = EMPPO("MlpPolicy", make_vec_env(ModeGoalEnv, n_envs=8, seed=args.seed), seed=args.seed, **args.kwargs)
    returns = []
    for part in range(5):
        model.learn(args.n // 5, reset_num_timesteps=part == 0)
        env = model.wrap_env(make_vec_env(ModeGoalEnv, n_envs=5, seed=100_000 + args.seed))
        returns.append(round(float(evaluate_policy(model, env, n_eval_episodes=50)[0]), 2))
    print(f"belief {args.belief}, seed {args.seed}, {args.kwargs}: return at each fifth of {args.n:,}: {returns}")


if __name__ == "__main__":
    main()
