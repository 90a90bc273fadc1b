"""Where a run's time goes: the phase clock on hand-built timings, and the phase table of real PPO and EM-PPO runs
(their phases sum to the training's wall time; what the timing wraps is restored at the end)."""

import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env
from stable_baselines3.common.logger import configure

from sb3_emmarl import EMPPO
from sb3_emmarl.common.callbacks import EvalCallback
from sb3_emmarl.common.mode_tasks import ModeCueEnv
from sb3_emmarl.common.phases import FLOOR, PHASES, PhaseClock, PhaseTimes, PhaseTotals, median_phase_table, phase_table


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def tick(self, seconds: float) -> None:
        self.now += seconds


def test_each_phase_counts_its_own_seconds_and_the_rest_is_other():
    tick = FakeClock()
    clock = PhaseClock(tick)
    clock.start()
    tick.tick(1.0)  # other
    with clock.phase("gradient epochs"):
        tick.tick(2.0)
        with clock.phase("logging"):  # inside the gradient epochs: the logging's own
            tick.tick(0.5)
        tick.tick(1.0)
    step = clock.timed(lambda: tick.tick(3.0), "environment")
    step()
    inner = clock.timed(lambda: tick.tick(0.25), "policy forward", unless=("gradient epochs",))
    inner()
    with clock.phase("gradient epochs"):
        inner()  # a forward pass inside the gradient epochs counts for them
    assert clock.stop() == pytest.approx(8.0)
    assert clock.seconds == {**dict.fromkeys(PHASES, 0.0), "other": 1.0, "gradient epochs": 3.25, "logging": 0.5,
                             "environment": 3.0, "policy forward": 0.25}
    assert sum(clock.seconds.values()) == pytest.approx(clock.wall) and clock.floor == pytest.approx(3.5)
    table = phase_table(clock.seconds, clock.wall)
    assert "gradient epochs" in table and "40.6%" in table and "wall / floor 2.29" in table and "E-step" not in table


def test_bad_phases_and_a_clock_used_out_of_order_are_refused():
    clock = PhaseClock(FakeClock())
    with pytest.raises(ValueError, match=r"phase must be one of \['environment', .*got 'training'"):
        clock.enter("training")
    with pytest.raises(RuntimeError, match="not running"):
        clock.stop()
    clock.start()
    clock.enter("environment")
    with pytest.raises(RuntimeError, match="leaving phase 'logging' while 'environment' is the innermost"):
        clock.leave("logging")
    with pytest.raises(RuntimeError, match="already running"):
        clock.start()


def test_runs_add_up_and_arms_taking_turns_give_their_medians():
    totals = PhaseTotals()
    totals.add({"environment": 1.0, "gradient epochs": 2.0, "other": 1.0}, 4.0)
    totals.add({"environment": 3.0, "policy forward": 1.0, "gradient epochs": 2.0}, 6.0)
    assert totals.runs == 2 and totals.wall == 10.0
    assert totals.seconds == {**dict.fromkeys(PHASES, 0.0), "environment": 4.0, "gradient epochs": 4.0,
                              "policy forward": 1.0, "other": 1.0}
    table = totals.table()
    assert table.startswith("where the training time of 2 runs went") and "wall / floor 2.00" in table
    with pytest.raises(ValueError, match=r"phases must be among .* got \['training'\]"):
        totals.add({"training": 1.0}, 1.0)
    with pytest.raises(ValueError, match="wall time is needed"):
        totals.add({"environment": 1.0})
    turns = {"ppo": [{"environment": 1.0, "gradient epochs": 1.0}, {"environment": 3.0, "gradient epochs": 2.0},
                     {"environment": 2.0, "gradient epochs": 3.0}],
             "em_ppo": [{"environment": 1.0, "E-step": 0.5, "gradient epochs": 4.0}]}
    lines = median_phase_table(turns, {"ppo": [2.0, 5.0, 6.0], "em_ppo": [8.0]}).splitlines()
    assert lines[1].split() == ["arm", "env", "gradients", "E-step", "wall/floor"]
    assert lines[2].split() == ["ppo", "2.00", "2.00", "0.00", "2.50"]  # medians 2 and 2; wall 5 over floor 2
    assert lines[3].split() == ["em_ppo", "1.00", "4.00", "0.50", "2.00"]


class Counting(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.steps = 0

    def _on_step(self) -> bool:
        self.steps += 1
        return True


def cue_env(n_envs: int = 2):
    return sb3_make_vec_env(lambda: ModeCueEnv(length=10), n_envs=n_envs, seed=0)


def test_a_ppo_run_s_phases_sum_to_its_wall_time_and_its_callbacks_still_run(tmp_path, capsys):
    model = PPO("MlpPolicy", cue_env(), n_steps=32, batch_size=32, n_epochs=2, seed=0)
    model.set_logger(configure(str(tmp_path / "log"), ["csv"]))
    forward, dump = model.policy.forward, model.logger.dump
    counting = Counting()
    eval_callback = EvalCallback(cue_env(1), n_eval_episodes=2, eval_freq=40, verbose=0)
    times = PhaseTimes([counting, eval_callback, CheckpointCallback(40, str(tmp_path))], verbose=1)
    model.learn(256, callback=times)
    seconds = times.seconds
    assert set(seconds) == set(PHASES) and sum(seconds.values()) == pytest.approx(times.wall, rel=1e-9)
    for phase in ("environment", "policy forward", "gradient epochs", "evaluation", "checkpoints", "callbacks"):
        assert seconds[phase] > 0.0, phase
    assert seconds["E-step"] == 0.0 and seconds["belief"] == 0.0
    assert counting.steps == 128 and eval_callback.n_calls == 128 and list(tmp_path.glob("*.zip"))
    assert "forward" not in vars(model.policy) and model.policy.forward == forward and model.logger.dump == dump
    assert "step_wait" not in vars(model.env)
    out = capsys.readouterr().out
    assert "where the run's time went" in out and f"floor ({' + '.join(FLOOR)})" in out
    logged = (tmp_path / "log" / "progress.csv").read_text().splitlines()[0].split(",")
    assert {"time/gradient_epochs", "time/environment", "time/policy_forward", "time/e_step"} <= set(logged)
    model.save(tmp_path / "after.zip")
    PPO.load(tmp_path / "after.zip")  # nothing the timing wrapped is saved
    model.learn(64, callback=times, reset_num_timesteps=False)  # a second learn adds to the same figures
    assert times.wall > sum(seconds.values()) and sum(times.seconds.values()) == pytest.approx(times.wall, rel=1e-9)
    totals = PhaseTotals()
    totals.add(times)
    assert totals.seconds == times.seconds and totals.wall == times.wall and totals.runs == 1


def test_em_ppo_s_belief_and_e_step_have_phases_of_their_own():
    model = EMPPO("MlpPolicy", cue_env(), n_steps=32, batch_size=32, n_epochs=1, seed=0,
                  latent_kwargs=dict(e_step_every=32))
    times = PhaseTimes()
    model.learn(192, callback=times)
    seconds = times.seconds
    assert seconds["belief"] > 0.0 and seconds["E-step"] > 0.0 and seconds["environment"] > 0.0
    assert sum(seconds.values()) == pytest.approx(times.wall, rel=1e-9)
    assert "add" not in vars(model.e_step) and "step_wait" not in vars(model.env)


def test_em_speed_times_ppo_and_mappo_on_zone_patrol_by_phase(capsys):
    from scripts import load_benchmark

    assert load_benchmark("em_speed").main(["--env", "ZonePatrol-v1", "--algos", "ppo", "mappo", "-n", "512",
                                            "--rounds", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.startswith("ZonePatrol-v1 {}: 512 agent-steps per turn") for line in lines)
    assert any(line.startswith("the machine's load average: ") for line in lines)
    table = lines[next(i for i, line in enumerate(lines) if line.startswith("median seconds per turn by phase")) + 1:]
    columns = table[0].split()
    assert columns[0] == "arm" and "gradients" in columns and "belief" not in columns  # (neither has a belief)
    rows = {row.split()[0]: [float(v) for v in row.split()[1:]] for row in table[1:3]}
    assert set(rows) == {"ppo", "mappo"} and all(row[-1] >= 1.0 for row in rows.values())  # wall over floor
    with pytest.raises(SystemExit):
        load_benchmark("em_speed").main(["--env", "ZonePatrol-v9"])
