"""EM-PPO's E-step on a schedule of its own (``latent_kwargs["e_step_every"]``, agent-steps), whatever ``n_steps`` is."""

import pytest
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

from sb3_emmarl import EMDDPG, EMPPO
from sb3_emmarl.common.latent.callback import EMCallback
from sb3_emmarl.common.mode_tasks import ModeCueEnv


def cue_env(n_envs: int = 4):
    return make_vec_env(lambda: ModeCueEnv(length=10), n_envs=n_envs, seed=0)


def em_ppo(**latent_kwargs) -> EMPPO:
    window = {"e_step_kwargs": {"window": 100}}
    return EMPPO("MlpPolicy", cue_env(), n_steps=64, batch_size=64, n_epochs=1, seed=0,
                 latent_kwargs={**window, **latent_kwargs})


class UpdatesAtRolloutEnd(BaseCallback):
    """The E-steps run by each rollout's end, before its policy update."""

    def __init__(self) -> None:
        super().__init__()
        self.counts: list[int] = []

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        self.counts.append(self.model.e_step.n_updates)


def test_e_steps_run_every_e_step_every_agent_steps_across_rollouts_and_before_the_first_update():
    model = em_ppo(e_step_every=100)  # 256 agent-steps per rollout
    seen = UpdatesAtRolloutEnd()
    model.learn(768, callback=seen)
    assert model.e_step.n_updates == 768 // 100
    assert model._e_step_steps == 768 % 100
    # during each rollout, before its update: 2 E-steps by the first rollout's end (at 100 and 200 agent-steps), then
    # 5 by the second's (300, 400, 500), the one at 300 on rows of both rollouts
    assert seen.counts == [2, 5, 7]


def test_without_it_one_e_step_runs_per_rollout_at_its_end():
    model = em_ppo()
    seen = UpdatesAtRolloutEnd()
    model.learn(768, callback=seen)
    assert seen.counts == [0, 1, 2] and model.e_step.n_updates == 3


def test_the_e_step_gets_every_transition_of_the_rollout_once():
    totals = []
    for latent_kwargs in ({}, {"e_step_every": 100}, {"e_step_every": 7}):
        model = em_ppo(**latent_kwargs)
        model.learn(512)
        totals.append(sum(len(part) for part in model.e_step.memory))
    # 128 steps on each of 4 copies, 10-step episodes: every step but the 12 episodes' last per copy has its successor
    # in its episode
    assert totals == [512 - 4 * 12] * 3


def test_the_schedule_is_saved_and_a_loaded_model_keeps_counting(tmp_path):
    model = em_ppo(e_step_every=100)
    model.learn(256)
    model.save(tmp_path / "model.zip")
    loaded = EMPPO.load(tmp_path / "model.zip", env=cue_env())
    assert loaded.latent_config.e_step_every == 100 and loaded._e_step_steps == 56
    loaded.learn(256, reset_num_timesteps=False)
    assert loaded.e_step.n_updates == 512 // 100


@pytest.mark.parametrize("build, message", [
    (lambda: em_ppo(e_step_every=100, e_step_interval=2), "give one E-step schedule"),
    (lambda: em_ppo(e_step_every=0), r"e_step_every must be null or an int in \[1, "),
    (lambda: EMDDPG("MlpPolicy", "Pendulum-v1", latent_kwargs={"e_step_every": 100}), "is EM-PPO's"),
    (lambda: EMCallback(latent_kwargs={"e_step_every": 100, "e_step_interval": 4}), "e_step_interval"),
])
def test_a_second_schedule_or_an_owner_without_one_is_refused_with_a_message(build, message):
    with pytest.raises(ValueError, match=message):
        build()
