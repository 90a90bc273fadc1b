"""The environments' evidence as plug-ins of the latent model (``common/latent/evidence.py``), and models saved before.

``data/em_ppo_0_21_0.zip`` is an EM-PPO saved by sb3-emmarl 0.21.0 (before the plug-ins): 200 agent-steps on a reserve of
2 UAVs on 20 x 20, 20 steps an episode, ``n_steps=100, batch_size=64, n_epochs=2, decoder_hidden=(8,),
policy_kwargs={"net_arch": [8]}, seed=0`` (its E-step holds the reading counts; SB3's members, deflated to keep it small).
"""

from pathlib import Path

import numpy as np

from sb3_emmarl import EMPPO
from sb3_emmarl.common.vec_env import make_vec_env

DATA = Path(__file__).parent / "data"
#: The reserve the saved model was trained on.
TINY = {"n_uavs": 2, "grid_size": 20, "max_cycles": 20}
#: What 0.21.0 predicted with the saved model, deterministically, over the first six steps of the reserve of seed 0
#: (the belief carried in ``state``), and the two UAVs' evidence per component after them.
SAVED_ACTIONS = [[14, 9], [14, 14], [6, 14], [9, 6], [9, 9], [9, 9]]
SAVED_EVIDENCE = [[-742.4769285065754, -657.7297416281575, -714.8286995883109, -713.2980385114427],
                  [-684.5819969870273, -638.643938197482, -686.2381928734687, -645.5469206258974]]


def test_a_model_saved_by_0_21_0_loads_and_predicts_as_it_did():
    model = EMPPO.load(DATA / "em_ppo_0_21_0.zip")
    assert model.feature_spec["kind"] == "reserve" and model.policy.latent_model.has_counts
    assert model.e_step is not None and len(model.e_step.count_table["ids"]) > 0  # the E-step's counts came back
    env = make_vec_env(1, seed=0, env_kwargs=TINY)
    obs, state, starts, actions = env.reset(), None, np.ones(env.num_envs, dtype=bool), []
    for _ in range(len(SAVED_ACTIONS)):
        action, state = model.predict(obs, state=state, episode_start=starts, deterministic=True)
        actions.append(action.tolist())
        obs, _, starts, _ = env.step(action)
    assert actions == SAVED_ACTIONS
    np.testing.assert_allclose(np.asarray(state)[:, :4], SAVED_EVIDENCE, rtol=1e-9)
