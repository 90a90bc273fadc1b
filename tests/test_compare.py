"""The method comparison (``zoo/compare.py``): its paired tables on hand-built records, its flags and variants, and
the evaluation of finished runs again (``--reuse-runs``)."""


import numpy as np
import pytest
import yaml
from scipy import stats
from scripts import load_benchmark, load_study

from sb3_emmarl.common.vec_env import LINKS_KEY, make_vec_env
from sb3_emmarl.zoo.compare import (
    DEFAULT_VARIANTS,
    compare_main,
    compare_parser,
    difference_header,
    difference_rows,
    difference_table,
    finished_run,
    oracle_gap_share,
    paired_over_seeds,
    parse_variant,
    summary_table,
)
from sb3_emmarl.zoo.exp_manager import zoo_hyperparams
from wildlife_reserve import reserve_v1


def records(team_reward: list[float], seeds: list[int] | None = None, **metrics: list[float]) -> list[dict]:
    """One record per seed (seeds ``0, 1, ...`` unless given) with the given per-seed values."""
    seeds = list(range(len(team_reward))) if seeds is None else seeds
    defaults = {"detection_rate": [0.5] * len(seeds), "coverage_efficiency": [0.5] * len(seeds)}
    columns = {"team_reward": team_reward, **defaults, **metrics}
    return [{"seed": seed, **{k: float(v[i]) for k, v in columns.items()}} for i, seed in enumerate(seeds)]


def constant(value: float, n: int = 3) -> list[dict]:
    return records([value] * n)


def test_the_oracle_share_is_the_variants_gain_over_the_oracles_gain():
    results = {"ppo": constant(1), "oracle_ppo": constant(5), "em_ppo": constant(3), "no_latent": constant(0)}
    assert oracle_gap_share(results, "em_ppo", "ppo", "oracle_ppo") == "0.50"
    assert oracle_gap_share(results, "oracle_ppo", "ppo", "oracle_ppo") == "1.00"
    assert oracle_gap_share(results, "no_latent", "ppo", "oracle_ppo") == "-0.25"
    # Means over seeds, not per-seed shares: baseline mean 1, oracle mean 4, variant mean 2 -> 1/3.
    uneven = {"ppo": records([0, 2]), "oracle_ppo": records([3, 5]), "em_ppo": records([1, 3])}
    assert oracle_gap_share(uneven, "em_ppo", "ppo", "oracle_ppo") == "0.33"


@pytest.mark.parametrize("oracle_reward", [1, 0.5])
def test_no_oracle_share_when_the_oracle_does_not_beat_the_baseline(oracle_reward):
    results = {"ppo": constant(1), "oracle_ppo": constant(oracle_reward), "em_ppo": constant(3)}
    assert oracle_gap_share(results, "em_ppo", "ppo", "oracle_ppo") == "n/a (oracle gap <= 0)"


def test_a_dash_for_the_oracle_share_when_the_oracle_was_not_run():
    results = {"ppo": constant(1), "em_ppo": records([3, 2, 4])}
    assert oracle_gap_share(results, "em_ppo", "ppo", "oracle_ppo") == "-"
    (row,) = [row for row in difference_rows(results, "ppo", "oracle_ppo") if row[1] == "team_reward"]
    assert row[-1] == "-"
    assert "no oracle variant ('oracle_ppo') was run" in difference_header(results, "ppo", "oracle_ppo")
    assert "(variant - ppo) / (oracle_ppo - ppo)" in difference_header({**results, "oracle_ppo": constant(5)}, "ppo",
                                                                       "oracle_ppo")


def test_difference_rows_pair_by_seed_with_scipys_p_values_and_higher_on_counts():
    baseline = records([1.0, 2.0, 2.5, 0.5, 3.0], detection_rate=[0.1, 0.2, 0.3, 0.4, 0.5])
    variant = records([1.5, 1.0, 4.0, 2.5, 3.1], detection_rate=[0.1, 0.2, 0.3, 0.4, 0.5])
    oracle = records([4.0, 5.0, 6.0, 3.0, 5.0], detection_rate=[0.3, 0.3, 0.3, 0.3, 0.3])
    results = {"ppo": baseline, "em_ppo": variant, "oracle_ppo": oracle}
    rows = {(v, m): tuple(rest) for v, m, *rest in difference_rows(results, "ppo", "oracle_ppo")}
    assert {v for v, _ in rows} == {"em_ppo", "oracle_ppo"}  # every variant but the baseline
    assert [m for v, m in rows if v == "em_ppo"] == ["team_reward", "detection_rate", "coverage_efficiency"]
    difference, p_value, higher_on, share = rows[("em_ppo", "team_reward")]
    a = np.array([r["team_reward"] for r in variant])
    b = np.array([r["team_reward"] for r in baseline])
    assert difference == pytest.approx((a - b).mean())
    assert p_value == pytest.approx(stats.ttest_rel(a, b).pvalue)
    assert higher_on == "4/5"
    assert share == f"{(a.mean() - b.mean()) / (4.6 - b.mean()):.2f}"
    # The same values on every seed: no difference, p 1.0, higher on none; the share only for team_reward.
    assert rows[("em_ppo", "detection_rate")] == (0.0, 1.0, "0/5", "")
    assert rows[("oracle_ppo", "detection_rate")][2] == "2/5"
    assert rows[("oracle_ppo", "team_reward")][1:] == (pytest.approx(stats.ttest_rel(
        [r["team_reward"] for r in oracle], b).pvalue), "5/5", "1.00")


def test_p_is_one_with_fewer_than_two_seeds():
    results = {"ppo": records([1.0]), "em_ppo": records([3.0])}
    test = paired_over_seeds(results, "em_ppo", "ppo", "team_reward")
    assert test.p_value == 1.0 and test.higher_on == "1/1"


@pytest.mark.parametrize("em_seeds", [[0, 1, 3], [2, 1, 0], [0, 1], [0, 0, 1]])
def test_seed_lists_that_differ_are_rejected_naming_the_variants(em_seeds):
    results = {"ppo": records([1, 2, 3], seeds=[0, 1, 2]),
               "em_ppo": records([1.0] * len(em_seeds), seeds=em_seeds)}
    with pytest.raises(ValueError, match=r"'em_ppo' and 'ppo' must be evaluated on the same seeds") as error:
        paired_over_seeds(results, "em_ppo", "ppo", "team_reward")
    assert str(em_seeds) in str(error.value)
    with pytest.raises(ValueError, match="same seeds"):
        difference_rows(results, "ppo", "oracle_ppo")


def test_the_tables_show_every_variant_and_a_dash_for_missing_latent_metrics():
    results = {"em_ppo": records([3, 4], latent_accuracy_50=[0.6, 0.8]), "ppo": constant(1, 2),
               "frozen_e_step": records([2, 1.5], latent_accuracy_50=[0.3, 0.3])}
    summary = summary_table(results, ("team_reward", "latent_accuracy_50")).splitlines()
    assert summary[1].split() == ["em_ppo", "3.500", "+-", "0.500", "0.700", "+-", "0.100"]
    assert summary[2].split() == ["ppo", "1.000", "+-", "0.000", "-"]
    differences = difference_table(results, "ppo", "oracle_ppo").splitlines()
    assert "p (paired t)" in differences[0] and "oracle gap recovered" in differences[0]
    assert [line.split()[:2] for line in differences[1:]] == [
        [v, m] for v in ("em_ppo", "frozen_e_step") for m in ("team_reward", "detection_rate", "coverage_efficiency")]


def test_parse_variant_on_the_default_variants():
    assert [parse_variant(v) for v in DEFAULT_VARIANTS] == [
        ("em_ppo", "em_ppo", []),
        ("ppo", "ppo", []),
        ("ppo_lstm", "ppo_lstm", []),
        ("oracle_ppo", "oracle_ppo", []),
        ("no_latent", "em_ppo", ["latent_kwargs:dict(use_latent=False)"]),
        ("frozen_e_step", "em_ppo", ["latent_kwargs:dict(freeze_e_step=True)"]),
    ]
    args = compare_parser().parse_args([])
    assert args.variants == list(DEFAULT_VARIANTS) and (args.baseline, args.oracle) == ("ppo", "oracle_ppo")


@pytest.mark.parametrize("flags, message", [
    (["--baseline", "a2c"], "--baseline 'a2c' is not among the variants"),
    (["--variants", "em_ppo", "ppo_lstm"], "--baseline 'ppo' is not among the variants"),
    (["--variants", "ppo", "x=ppo:gamma=0.9", "x=ppo"], "distinct names"),
    (["--variants", "ppo", "bad=nope"], "unknown algorithm 'nope'"),
])
def test_the_parser_rejects_bad_flags_before_training(flags, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        compare_main(flags)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


TINY_RUN = ["-n", "256", "--seeds", "0", "--eval-episodes", "1", "--variants", "ppo=ppo:n_steps=32,batch_size=64",
            "--oracle", "-", "--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:40"]


def test_reuse_runs_evaluates_the_finished_runs_again_and_refuses_runs_trained_otherwise(tmp_path, capsys):
    folder = ["-f", str(tmp_path)]
    assert compare_main([*TINY_RUN, *folder]) == 0
    trained = capsys.readouterr().out
    runs = sorted(tmp_path.glob("ppo/seed_0/ppo/WildlifeReserve-v1_*"))
    assert [run.name for run in runs] == ["WildlifeReserve-v1_1"]

    # Evaluated again, not trained again: no new run folder, the same evaluation to the digit.
    assert compare_main([*TINY_RUN, *folder, "--reuse-runs"]) == 0
    assert sorted(tmp_path.glob("ppo/seed_0/ppo/WildlifeReserve-v1_*")) == runs
    row = next(line for line in trained.splitlines() if line.startswith("ppo seed 0:"))
    assert row.split(", ", 1)[1] in capsys.readouterr().out

    # Another budget: refused before anything trains, naming the setting.
    flags = [*TINY_RUN, *folder, "--reuse-runs"]
    flags[1] = "512"
    assert compare_main(flags) == 2
    assert "was trained with n_timesteps 256, not 512" in capsys.readouterr().err
    assert sorted(tmp_path.glob("ppo/seed_0/ppo/WildlifeReserve-v1_*")) == runs


def test_finished_run_reads_todays_yaml_through_its_base(tmp_path):
    # em_ppo.yml starts from ppo.yml (base: ppo): a run trained with the resolved settings is today's.
    run = tmp_path / "em_ppo" / "WildlifeReserve-v1_1"
    (run / "WildlifeReserve-v1").mkdir(parents=True)
    (run / "WildlifeReserve-v1" / "config.yml").write_text(yaml.safe_dump(zoo_hyperparams("em_ppo")))
    (run / "WildlifeReserve-v1" / "args.yml").write_text(yaml.safe_dump({"algo": "em_ppo", "seed": 0,
                                                                         "n_timesteps": 256}))
    (run / "run_stats.json").write_text("{}")
    (run / "WildlifeReserve-v1.zip").write_bytes(b"")
    assert finished_run(tmp_path, "em_ppo", 0, 256, [], None) == run
    # A run trained with the settings em_ppo.yml had before 0.13.0 is not today's.
    (run / "WildlifeReserve-v1" / "config.yml").write_text(yaml.safe_dump({**zoo_hyperparams("em_ppo"), "n_epochs": 5}))
    with pytest.raises(ValueError, match="trained with n_epochs 5, not 10"):
        finished_run(tmp_path, "em_ppo", 0, 256, [], None)


def test_finished_run_merges_a_variants_latent_settings_and_reads_runs_saved_before_latent_kwargs(tmp_path):
    from sb3_emmarl.zoo.algos import merge_hyperparams

    run = tmp_path / "em_ppo" / "WildlifeReserve-v1_1"
    (run / "WildlifeReserve-v1").mkdir(parents=True)
    params = ["latent_kwargs:dict(use_latent=False)"]
    trained = merge_hyperparams(zoo_hyperparams("em_ppo"), {"latent_kwargs": {"use_latent": False}})
    (run / "WildlifeReserve-v1" / "config.yml").write_text(yaml.safe_dump(trained))
    (run / "WildlifeReserve-v1" / "args.yml").write_text(yaml.safe_dump({
        "algo": "em_ppo", "seed": 0, "n_timesteps": 256, "hyperparams": {"latent_kwargs": {"use_latent": False}}}))
    (run / "run_stats.json").write_text("{}")
    (run / "WildlifeReserve-v1.zip").write_bytes(b"")
    assert finished_run(tmp_path, "em_ppo", 0, 256, params, None) == run  # the YAML's other latent settings kept
    # the same run's config as 0.22.0 wrote it: each latent setting a hyperparameter of its own
    flat = {**{k: v for k, v in trained.items() if k != "latent_kwargs"}, **trained["latent_kwargs"]}
    (run / "WildlifeReserve-v1" / "config.yml").write_text(yaml.safe_dump(flat))
    assert finished_run(tmp_path, "em_ppo", 0, 256, params, None) == run


def test_finished_run_checks_the_runs_hyperparameters_against_todays_yaml(tmp_path):
    assert finished_run(tmp_path, "ppo", 0, 256, [], None) is None  # no run at all
    run = tmp_path / "ppo" / "WildlifeReserve-v1_1"
    params = run / "WildlifeReserve-v1"
    params.mkdir(parents=True)
    config = {**zoo_hyperparams("ppo"), "gamma": 0.9, "env_kwargs": {"n_uavs": 2}}
    (params / "config.yml").write_text(yaml.safe_dump(config))
    (params / "args.yml").write_text(yaml.safe_dump({"algo": "ppo", "seed": 3, "n_timesteps": 256,
                                                     "hyperparams": {"gamma": 0.9}, "env_kwargs": {"n_uavs": 2}}))
    (run / "run_stats.json").write_text("{}")
    assert finished_run(tmp_path, "ppo", 3, 256, ["gamma:0.9"], {"n_uavs": 2}) is None  # no final model: unfinished
    (run / "WildlifeReserve-v1.zip").write_bytes(b"")
    assert finished_run(tmp_path, "ppo", 3, 256, ["gamma:0.9"], {"n_uavs": 2}) == run
    with pytest.raises(ValueError, match="trained with seed 3, not 4"):
        finished_run(tmp_path, "ppo", 4, 256, ["gamma:0.9"], {"n_uavs": 2})
    with pytest.raises(ValueError, match=r"trained with env_kwargs \{'n_uavs': 2\}, not None"):
        finished_run(tmp_path, "ppo", 3, 256, ["gamma:0.9"], None)
    # The flags agree but the YAML has changed since (here: the run's config says 0.9 where the YAML now says
    # another discount): refused, naming the hyperparameter.
    (params / "args.yml").write_text(yaml.safe_dump({"algo": "ppo", "seed": 3, "n_timesteps": 256,
                                                     "env_kwargs": {"n_uavs": 2}}))
    with pytest.raises(ValueError, match=f"trained with gamma 0.9, not {zoo_hyperparams('ppo')['gamma']!r}"):
        finished_run(tmp_path, "ppo", 3, 256, [], {"n_uavs": 2})


def test_the_fusion_study_s_all_links_lists_every_teammate_of_the_copy_and_nobody_else():
    fusion = load_study("fusion")
    venv = fusion.AllLinks(make_vec_env(2, seed=0, env_kwargs={"n_uavs": 3, "grid_size": 20, "max_cycles": 5}))
    try:
        venv.reset()
        for _ in range(6):  # across an episode end
            _, _, _, infos = venv.step(np.zeros(venv.num_envs, dtype=np.int64))
            assert [info[LINKS_KEY] for info in infos] == [(1, 2), (0, 2), (0, 1), (4, 5), (3, 5), (3, 4)]
    finally:
        venv.close()


def test_the_fusion_study_runs_end_to_end_on_tiny_em_ppo_runs(tmp_path, capsys):
    flags = ["-n", "128", "--seeds", "0", "1", "--eval-episodes", "1", "-f", str(tmp_path), "--env-kwargs", "n_uavs:2",
             "grid_size:20", "max_cycles:8"]
    assert compare_main(["--variants", "em_ppo", "ppo", "--oracle", "ppo", *flags]) == 0
    capsys.readouterr()
    assert load_study("fusion").main(["-f", str(tmp_path), "--seeds", "0", "1", "--eval-episodes", "1",
                                          "--all-links"]) == 0
    out = capsys.readouterr().out
    assert "fusion on / off" in out and "with every link up" in out
    assert len([line for line in out.splitlines() if line.startswith("latent_accuracy_50")]) == 2


def test_parse_variant_keeps_commas_inside_brackets_and_quotes():
    name, algo, items = parse_variant("norm=ppo:normalize=dict(norm_obs=False, norm_reward=True),ent_coef=0.03")
    assert (name, algo) == ("norm", "ppo")
    assert items == ["normalize:dict(norm_obs=False, norm_reward=True)", "ent_coef:0.03"]
    assert parse_variant("x=ppo:policy_kwargs=dict(net_arch=[64, 64]),gamma=0.9")[2] == [
        "policy_kwargs:dict(net_arch=[64, 64])", "gamma:0.9"]
    assert parse_variant("x=ppo:a='1,2',b=3")[2] == ["a:'1,2'", "b:3"]


def test_vec_normalize_stats_names_the_file_only_where_a_run_saved_one(tmp_path):
    from sb3_emmarl.common.checkpoints import VEC_NORMALIZE_FILE, vec_normalize_stats

    assert vec_normalize_stats(tmp_path) is None
    (tmp_path / VEC_NORMALIZE_FILE).write_bytes(b"")
    assert vec_normalize_stats(tmp_path) == str(tmp_path / "vecnormalize.pkl")


def test_the_spread_study_counts_the_boundary_corners_and_how_alike_the_moves_are():
    spread = load_study("team_spread")
    for continuous in (True, False):
        env_kwargs = {"n_uavs": 3, "grid_size": 20, "max_cycles": 100, "continuous_actions": continuous}
        own = reserve_v1.parallel_env(**env_kwargs).observation_layout["own"][0]
        monitor = spread.SpreadMonitor(make_vec_env(1, seed=0, env_kwargs=env_kwargs), own, 3, continuous)
        try:
            monitor.reset()
            if continuous:  # every UAV flies up and left: one direction, and after at most 20 steps the corner
                actions = np.tile(np.array([-1.0, -1.0, 0.0], dtype=np.float32), (3, 1))
            else:  # up, down, stay: the two moving UAVs fly opposite ways (the one staying is not a move)
                actions = np.array([1, 2, 0], dtype=np.int64)
            for _ in range(40):
                monitor.step(actions)
            summary = monitor.summary()
        finally:
            monitor.close()
        if continuous:
            assert summary["alignment"] == pytest.approx(1.0) and 0.5 <= summary["corner"] <= summary["edge"] <= 1.0
        else:
            assert summary["alignment"] == pytest.approx(-1.0)


def test_the_spread_study_runs_end_to_end_on_a_tiny_ddpg_run(tmp_path, capsys):
    flags = ["-n", "64", "--seeds", "0", "--eval-episodes", "1", "-f", str(tmp_path), "--env-kwargs", "n_uavs:2",
             "grid_size:20", "max_cycles:8"]
    assert compare_main(["--variants", "ddpg", "--baseline", "ddpg", "--oracle", "-", "--ratio", "ddpg", "ddpg",
                         *flags]) == 0
    capsys.readouterr()
    assert load_study("team_spread").main(["-f", str(tmp_path), "--variants", "ddpg", "--seeds", "0",
                                               "--eval-episodes", "2"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("ddpg")]
    assert len(rows) == 1 and rows[0][:2] == ["ddpg", "0"]
    edge, corner, alignment = map(float, rows[0][4:])
    assert 0.0 <= corner <= edge <= 1.0 and -1.0 <= alignment <= 1.0


def test_the_e_step_memory_benchmark_runs_and_rejects_a_bad_window(capsys):
    memory = load_benchmark("e_step_memory")
    assert memory.main(["-n", "200", "--window", "3", "--interval", "2"]) == 0
    assert "on the last 3: peak resident memory" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        memory.main(["--window", "0"])
    assert "--window must be >= 1, got 0" in capsys.readouterr().err
