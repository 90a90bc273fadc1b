"""Do the single-agent hidden-mode tasks train as before this day's changes? A digest of EM-PPO's parameters after six
rollouts (E-steps included) on each of the four tasks, with torch's scalar kernels (as tests/test_training_digest.py).

Run it once on each tree and compare the lines, e.g. with a worktree of the commit before the changes::

    git worktree add /tmp/old aeae706
    PYTHONPATH=/tmp/old:/tmp/old/envs ATEN_CPU_CAPABILITY=default MKL_CBWR=COMPATIBLE OMP_NUM_THREADS=1 \\
        python docs/lab/2026-12-07/unchanged_training.py
    ATEN_CPU_CAPABILITY=default MKL_CBWR=COMPATIBLE OMP_NUM_THREADS=1 python docs/lab/2026-12-07/unchanged_training.py
"""

import hashlib

import torch as th
from stable_baselines3.common.env_util import make_vec_env

import sb3_emmarl
from sb3_emmarl import EMPPO
from sb3_emmarl.common.mode_tasks import ModeCueEnv, ModeDynamicsEnv, ModeGoalEnv, ModeReachEnv

th.set_num_threads(1)
print(sb3_emmarl.__file__)
for task in (ModeCueEnv, ModeDynamicsEnv, ModeReachEnv, ModeGoalEnv):
    model = EMPPO("MlpPolicy", make_vec_env(task, n_envs=8, seed=0), seed=0, n_components=4)
    model.learn(8 * 128 * 6)
    digest = hashlib.sha256()
    for key, value in sorted(model.policy.state_dict().items()):
        digest.update(key.encode())
        digest.update(value.detach().cpu().numpy().tobytes())
    print(task.__name__, digest.hexdigest()[:16])
