"""Training is pinned: a short run of PPO, EM-PPO, EM-DDPG and VDN+EM with the zoo's settings on a small reserve gives
the same parameters, to the bit, as when the digests were taken (sb3-emmarl 0.19.0, torch 2.13.0 CPU, one thread).

A change that means to leave training alone (a refactor, a faster path) must leave these digests alone; a change that
means to change training updates them and says so in the changelog."""

import hashlib

import pytest
import torch as th

from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.zoo.exp_manager import zoo_hyperparams, zoo_model

#: A small reserve: 2 UAVs on 20 x 20, 40 steps an episode.
TINY = {"n_uavs": 2, "grid_size": 20, "max_cycles": 40}
#: Each algorithm's overrides of its zoo settings (short rollouts and buffers, E-steps within the run), its agent-steps,
#: and the first 16 hex digits of the SHA-256 of its policy's parameters after training.
CASES = {
    "ppo": ({"n_steps": 32, "batch_size": 64}, 256, "aa97500dfd6f818c"),
    "em_ppo": ({"n_steps": 32, "batch_size": 64, "e_step_interval": 2}, 256, "67407c75b43491d7"),
    "em_ddpg": ({"buffer_size": 2000, "learning_starts": 100, "e_step_interval": 5, "batch_size": 64}, 400,
                "18fd66890bb71c67"),
    "vdn_em": ({"buffer_size": 2000, "learning_starts": 100, "e_step_interval": 5, "batch_size": 8}, 400,
               "1dff5e357d25ce0c"),
}


def parameters_digest(model) -> str:
    digest = hashlib.sha256()
    for key, value in sorted(model.policy.state_dict().items()):
        digest.update(key.encode())
        digest.update(value.detach().cpu().numpy().tobytes())
    return digest.hexdigest()[:16]


@pytest.mark.parametrize("algo", sorted(CASES))
def test_a_short_run_trains_the_same_parameters(algo):
    overrides, steps, expected = CASES[algo]
    threads = th.get_num_threads()
    th.set_num_threads(1)
    try:
        settings = zoo_hyperparams(algo)
        env = make_vec_env(1, seed=0, env_kwargs={**(settings.get("env_kwargs") or {}), **TINY})
        model = zoo_model(algo, env, seed=0, **overrides)
        model.learn(steps)
    finally:
        th.set_num_threads(threads)
    if algo != "ppo":
        assert "latent/log_likelihood" in model.logger.name_to_value, "no E-step ran: the digest would not cover EM"
    assert parameters_digest(model) == expected
