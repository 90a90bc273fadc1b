"""Scripted patrols, the metric summaries, and the command-line scripts."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scripts import load_benchmark

from sb3_emmarl.common.metrics import TEAM_METRICS, format_summary, summarize
from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.scripted import RandomPatrol, StalestBlockPatrol, run_patrol

ROOT = Path(__file__).resolve().parents[1]


def test_summarize_on_hand_built_records():
    records = [dict.fromkeys(TEAM_METRICS, 1.0), dict.fromkeys(TEAM_METRICS, 3.0)]
    summary = summarize(records)
    assert summary["detection_rate"] == (2.0, 1.0)
    assert list(summary) == list(TEAM_METRICS)
    assert "detection_rate" in format_summary(summary, "title").splitlines()[3]
    with_latent = [{**r, "latent_accuracy_50": a, "latent_nmi": 0.5} for r, a in zip(records, (0.25, 0.75))]
    summary = summarize(with_latent)  # the latent metrics a record holds follow the team's
    assert list(summary) == [*TEAM_METRICS, "latent_accuracy_50", "latent_nmi"]
    assert summary["latent_accuracy_50"] == (0.5, 0.25)


def test_summarize_rejects_bad_records():
    with pytest.raises(ValueError, match="at least one episode"):
        summarize([])
    with pytest.raises(ValueError, match=r"lack the metrics \['team_reward'"):
        summarize([{"coverage_efficiency": 1.0}])


def test_stalest_block_patrol_covers_more_than_random():
    env = reserve_v1.parallel_env(max_cycles=150)
    random_runs = run_patrol(env, RandomPatrol(env, seed=0), episodes=3, seed=0)
    scripted_runs = run_patrol(env, StalestBlockPatrol(env), episodes=3, seed=0)
    random_cov = np.mean([r["coverage_efficiency"] for r in random_runs])
    scripted_cov = np.mean([r["coverage_efficiency"] for r in scripted_runs])
    assert scripted_cov > random_cov + 0.15


def test_run_patrol_is_reproducible():
    env = reserve_v1.parallel_env(max_cycles=40)
    assert run_patrol(env, RandomPatrol(env, seed=1), 2, seed=3) == run_patrol(env, RandomPatrol(env, seed=1), 2, seed=3)


def test_stalest_block_patrol_refuses_continuous_actions():
    with pytest.raises(ValueError, match="continuous_actions=False"):
        StalestBlockPatrol(reserve_v1.parallel_env(continuous_actions=True))


def run(script, *args):
    return subprocess.run([sys.executable, str(ROOT / script), *args], capture_output=True, text=True, timeout=300)


def test_patrol_script_prints_the_team_metrics():
    result = run("zoo/patrol.py", "--episodes", "1", "--env-kwargs", "max_cycles:30", "n_uavs:4")
    assert result.returncode == 0, result.stderr
    for metric in TEAM_METRICS:
        assert metric in result.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--env-kwargs", "n_uavs:0"], "n_uavs must be in [1, 1000], got 0"),
        (["--env-kwargs", "n_drones:3"], "n_drones"),
        (["--env-kwargs", "n_uavs=3"], "expects key:value pairs"),
        (["--env-kwargs", "region:forest"], "is not a valid Python value"),
        (["--episodes", "0"], "--episodes: must be an int in [1, 10000], got 0"),
    ],
)
def test_patrol_script_rejects_bad_arguments(args, message):
    result = run("zoo/patrol.py", *args)
    assert result.returncode != 0
    assert message in result.stderr


def test_env_speed_benchmark_prints_its_table():
    pytest.importorskip("mpe2")
    result = run("benchmarks/env_speed.py", "--uavs", "2", "4", "--seconds", "0.05", "--repeats", "1")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.strip().splitlines()
    assert "ratio" in lines[0] and len(lines) == 3
    assert float(lines[1].split()[1].replace(",", "")) > 0


def test_the_mode_evidence_probe_recovers_a_mode_given_as_input():
    probe = load_benchmark("mode_evidence")
    labels = np.repeat(np.arange(8), 20)
    assert (probe.probe_accuracy(np.eye(8)[labels], labels, np.eye(8), 8, epochs=40, seed=0) == np.arange(8)).all()


def test_the_summary_says_what_each_metric_is_and_which_way_is_better():
    from sb3_emmarl.common.metrics import LATENT_METRICS, METRIC_MEANINGS

    assert set(TEAM_METRICS) | set(LATENT_METRICS) | {"detections", "escapes", "intruders"} <= set(METRIC_MEANINGS)
    summary = summarize([dict.fromkeys(TEAM_METRICS, 1.0), dict.fromkeys(TEAM_METRICS, 3.0)])
    lines = format_summary(summary).splitlines()
    assert lines[0].startswith("team_reward") and lines[0].endswith("(higher is better)")
    assert next(line for line in lines if line.startswith("collisions")).endswith("(lower is better)")
    assert format_summary(summary, explain=False).splitlines()[0].rstrip().endswith("1.000")
    # A metric with no better direction says how to read it instead: belief_use's scale and its zero.
    belief = format_summary({"belief_use": (0.4, 0.1)})
    assert "0 when the policy ignores its belief" in belief and "is better" not in belief
    assert all(meaning for meaning, _ in METRIC_MEANINGS.values())


def test_a_finished_run_says_where_its_curves_are_and_what_to_run_next():
    from argparse import Namespace

    from sb3_emmarl.zoo.cli import next_steps

    args = Namespace(algo="em_ppo", env="WildlifeReserve-v1", tensorboard_log="runs", log_folder="logs")
    text = next_steps(args, "logs/em_ppo/WildlifeReserve-v1_1", 5120)
    assert "tensorboard --logdir runs" in text and "emmarl enjoy --algo em_ppo" in text and "-n 5120" in text
    text = next_steps(Namespace(**{**vars(args), "env": "ZonePatrol-v0", "tensorboard_log": ""}), "x", 10)
    assert "tensorboard" not in text and "zone_patrol_value.py" in text


def test_the_command_s_help_and_the_package_import_no_torch():
    """``emmarl --help`` lists the commands without torch or SB3 (the package's names are imported when first used)."""
    import subprocess
    import sys

    code = ("import sys; import sb3_emmarl; from sb3_emmarl.cli import main; main(['--help']); "
            "assert not {'torch', 'stable_baselines3'} & set(sys.modules); "
            "from sb3_emmarl import EMPPO; assert EMPPO.__name__ == 'EMPPO' and 'torch' in sys.modules; "
            "assert 'EMPPO' in dir(sb3_emmarl)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "train" in done.stdout
    with pytest.raises(AttributeError, match="no attribute 'EMPP0'"):
        import sb3_emmarl

        sb3_emmarl.EMPP0  # noqa: B018
