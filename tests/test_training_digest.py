"""Training is pinned: a short run of PPO, OraclePPO, EM-PPO, EM-DDPG and VDN+EM with the zoo's settings on a small
reserve gives the same parameters, to the bit, as when the digests were taken.

A change that means to leave training alone (a refactor, a faster path) must leave these digests alone; a change that
means to change training updates them and says so in the changelog.

Floating-point sums in torch's vectorised kernels and in MKL's matrix products depend on the CPU's instruction set: the
digests first pinned (sb3-emmarl 0.19.0, on the project's earlier machines) differ on an AVX2 machine at the very commit
that pinned them. Each run therefore trains in a process of its own with torch's scalar kernels
(``ATEN_CPU_CAPABILITY=default``) and MKL's reproducible paths (``MKL_CBWR=COMPATIBLE``), one thread, so that the
digest is the same on any x86-64 CPU (re-pinned at 0.21.0 with its Unreleased changes, whose training was checked
unchanged against the commit that first pinned them on one machine). ``python tests/test_training_digest.py ALGO``
prints a digest."""

import hashlib
import os
import subprocess
import sys

import pytest

#: A small reserve: 2 UAVs on 20 x 20, 40 steps an episode.
TINY = {"n_uavs": 2, "grid_size": 20, "max_cycles": 40}
#: Each algorithm's overrides of its zoo settings (short rollouts and buffers, E-steps within the run), its agent-steps,
#: and the first 16 hex digits of the SHA-256 of its policy's parameters after training.
CASES = {
    "ppo": ({"n_steps": 32, "batch_size": 64}, 256, "e7f97adda1dff97a"),
    "oracle_ppo": ({"n_steps": 32, "batch_size": 64}, 256, "9e623e3147c1efb6"),
    "em_ppo": ({"n_steps": 32, "batch_size": 64, "latent_kwargs": {"e_step_interval": 2}}, 256, "8e3d4bc7e6dd3bb0"),
    "em_ddpg": ({"buffer_size": 2000, "learning_starts": 100, "latent_kwargs": {"e_step_interval": 5}, "batch_size": 64},
                400,
                "cd0c9c0b8fa8fb19"),
    "vdn_em": ({"buffer_size": 2000, "learning_starts": 100, "latent_kwargs": {"e_step_interval": 5}, "batch_size": 8},
               400,
               "c0850a9c86753f76"),
}
#: The settings under which a digest does not depend on the CPU (read by torch and MKL when they load).
REPRODUCIBLE = {"ATEN_CPU_CAPABILITY": "default", "MKL_CBWR": "COMPATIBLE", "OMP_NUM_THREADS": "1",
                "MKL_NUM_THREADS": "1"}


def parameters_digest(model) -> str:
    digest = hashlib.sha256()
    for key, value in sorted(model.policy.state_dict().items()):
        digest.update(key.encode())
        digest.update(value.detach().cpu().numpy().tobytes())
    return digest.hexdigest()[:16]


def train_digest(algo: str) -> str:
    """The digest of ``algo``'s parameters after its short run, trained here (run in a :data:`REPRODUCIBLE` process)."""
    import torch as th

    from sb3_emmarl.common.vec_env import make_vec_env
    from sb3_emmarl.zoo.exp_manager import zoo_hyperparams, zoo_model

    overrides, steps, _ = CASES[algo]
    th.set_num_threads(1)
    settings = zoo_hyperparams(algo)
    env = make_vec_env(1, seed=0, env_kwargs={**(settings.get("env_kwargs") or {}), **TINY})
    model = zoo_model(algo, env, seed=0, **overrides)
    model.learn(steps)
    if algo.startswith(("em_", "vdn_em")) and "latent/log_likelihood" not in model.logger.name_to_value:
        raise AssertionError("no E-step ran: the digest would not cover EM")
    return parameters_digest(model)


@pytest.mark.parametrize("algo", sorted(CASES))
def test_a_short_run_trains_the_same_parameters(algo):
    done = subprocess.run([sys.executable, __file__, algo], capture_output=True, text=True, timeout=600,
                          env={**os.environ, **REPRODUCIBLE})
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split()[-1] == CASES[algo][2]


def test_the_settings_reach_torch():
    code = "import torch; print(torch.backends.cpu.get_cpu_capability())"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={**os.environ,
                                                                                            **REPRODUCIBLE})
    assert done.stdout.strip() == "DEFAULT"


if __name__ == "__main__":
    print(train_digest(sys.argv[1]))
