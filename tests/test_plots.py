"""``emmarl plot`` (sb3_emmarl/plots/): learning curves of team episodes from monitor files and of tensorboard
scalars, mean and spread over runs; per-seed bars whose axis one outlying seed does not flatten; one-line errors."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from sb3_emmarl import plots

ENV = "ZonePatrol-v0"


def write_monitor(run: Path, team_rewards: list[float], n_uavs: int, steps: int = 10, env: str = ENV) -> None:
    """A zoo run's monitor.csv as VecMonitor writes it on a parameter-sharing environment: one row per UAV episode,
    the ``n_uavs`` rows of a team episode together (each UAV's return the team reward), and its config.yml (in the
    run's ``env`` folder)."""
    run.mkdir(parents=True)
    lines = ["#" + json.dumps({"t_start": 1000.0, "env_id": "None"}), "r,l,t"]
    t = 0.0
    for reward in team_rewards:
        t += 1.0
        lines += [f"{reward},{steps},{t + 1e-4 * uav:.6f}" for uav in range(n_uavs)]
    (run / "monitor.csv").write_text("\n".join(lines) + "\n")
    (run / env).mkdir()
    (run / env / "config.yml").write_text(f"env_kwargs:\n  n_uavs: {n_uavs}\n")


def write_scalars(folder: Path, tag: str, points: dict[int, float]) -> None:
    """A tensorboard event file with one scalar, written with SB3's logger (torch's SummaryWriter)."""
    from stable_baselines3.common.logger import configure

    logger = configure(str(folder), ["tensorboard"])
    for step, value in points.items():
        logger.record(tag, value)
        logger.dump(step)
    logger.close()


@pytest.fixture
def logs(tmp_path: Path) -> Path:
    """Two PPO runs on teams of 2 UAVs: team rewards 1, 2, 3, 4 and 3, 4, 5, 6 over four team episodes of 10 steps."""
    write_monitor(tmp_path / "logs" / "ppo" / f"{ENV}_1", [1, 2, 3, 4], n_uavs=2)
    write_monitor(tmp_path / "logs" / "ppo" / f"{ENV}_2", [3, 4, 5, 6], n_uavs=2)
    return tmp_path / "logs"


def line_data(figure: Figure) -> tuple[np.ndarray, np.ndarray]:
    line = figure.axes[0].lines[0]
    return np.asarray(line.get_xdata(), dtype=float), np.asarray(line.get_ydata(), dtype=float)


def test_team_episodes_take_one_row_per_team(logs: Path):
    episodes = plots.team_episodes(logs / "ppo" / f"{ENV}_1", 2)
    assert episodes["r"].tolist() == [1, 2, 3, 4]
    assert episodes["l"].tolist() == [20, 20, 20, 20]  # agent-steps: 2 UAVs x 10 steps
    assert episodes["steps"].tolist() == [10, 10, 10, 10]
    with pytest.raises(ValueError, match="8 monitor rows, not whole team episodes of 3 UAVs"):
        plots.team_episodes(logs / "ppo" / f"{ENV}_1", 3)


def test_runs_know_their_team_size(logs: Path):
    runs = plots.zoo_runs([logs])
    assert [(r.algo, r.env_id, r.folder.name, r.agents_per_copy) for r in runs] == [
        ("ppo", ENV, f"{ENV}_1", 2), ("ppo", ENV, f"{ENV}_2", 2)]


def test_runs_saved_under_a_former_id_count_as_the_current_id_s(tmp_path: Path):
    write_monitor(tmp_path / "ppo" / "WildlifeReserve-v0_1", [1, 2], n_uavs=3, env="WildlifeReserve-v0")
    write_monitor(tmp_path / "ppo" / "WildlifeReserve-v1_1", [3, 4], n_uavs=2, env="WildlifeReserve-v1")
    runs = plots.zoo_runs([tmp_path], env_id="WildlifeReserve-v1")
    assert [(r.env_id, r.folder.name, r.team_size) for r in runs] == [
        ("WildlifeReserve-v1", "WildlifeReserve-v1_1", 2), ("WildlifeReserve-v1", "WildlifeReserve-v0_1", 3)]
    write_scalars(tmp_path / "tb" / "WildlifeReserve-v0" / "PPO_1", "rollout/ep_rew_mean", {50: 4.0})
    assert [r.folder.parent.name for r in plots.tensorboard_runs(tmp_path / "tb", runs)] == ["WildlifeReserve-v0"]


def test_monitor_curves_mean_and_standard_error(logs: Path, tmp_path: Path):
    output = tmp_path / "curves.png"
    assert plots.main(["-f", str(logs), "-w", "2", "-o", str(output)]) == 0
    assert output.stat().st_size > 0
    figure = plots.build_figure(plots.plot_parser().parse_args(["-f", str(logs), "-w", "2"]))
    x, y = line_data(figure)
    # Rolling means of 2 team episodes: 1.5, 2.5, 3.5 and 3.5, 4.5, 5.5 at 40, 60, 80 agent-steps; their mean over runs.
    assert (x[0], x[-1]) == (40.0, 80.0)
    np.testing.assert_allclose(y, np.interp(x, [40, 60, 80], [2.5, 3.5, 4.5]))
    assert "team reward, mean of 2 team episodes" in figure.axes[0].get_ylabel()
    assert figure.axes[0].get_legend().get_texts()[0].get_text() == "ppo (2 runs)"
    curve = plots.aggregate_curves([(np.array([40.0, 60, 80]), np.array([1.5, 2.5, 3.5])),
                                    (np.array([40.0, 60, 80]), np.array([3.5, 4.5, 5.5]))], points=3)
    np.testing.assert_allclose(curve.center, [2.5, 3.5, 4.5])
    np.testing.assert_allclose(curve.high - curve.center, 1.0)  # std (ddof 1) sqrt(2), over sqrt(2 runs)
    np.testing.assert_allclose(curve.center - curve.low, 1.0)


def test_quartile_band_and_wall_time(logs: Path, tmp_path: Path):
    write_monitor(logs / "ppo" / f"{ENV}_3", [0, 0, 0, 10], n_uavs=2)
    curve = plots.aggregate_curves([(np.array([0.0, 1]), np.array([v, v])) for v in (1.0, 2.0, 4.0, 8.0)],
                                   band="iqr", points=2)
    np.testing.assert_allclose(curve.center, 3.0)  # median of 1, 2, 4, 8
    np.testing.assert_allclose(curve.low, 1.75)  # numpy's linear quartiles
    np.testing.assert_allclose(curve.high, 5.0)
    figure = plots.build_figure(plots.plot_parser().parse_args(["-f", str(logs), "-w", "1", "-x", "time",
                                                                "--band", "iqr"]))
    x, y = line_data(figure)
    # Team episodes end at 1, 2, 3, 4 s (their last UAV's row 1e-4 s later): in seconds, the median of 3 runs.
    np.testing.assert_allclose(x[[0, -1]], [1.0001, 4.0001])
    assert y[-1] == pytest.approx(6.0)  # median of 4, 6, 10
    assert figure.axes[0].get_xlabel() == "wall time (s)"
    assert plots.main(["-f", str(logs), "-x", "time", "-w", "1", "-o", str(tmp_path / "curves.svg")]) == 0
    assert (tmp_path / "curves.svg").read_text().lstrip().startswith("<?xml")
    assert plots.main(["-f", str(logs), "-w", "1", "-o", str(tmp_path / "curves.pdf")]) == 0
    assert (tmp_path / "curves.pdf").read_bytes().startswith(b"%PDF")


def test_tensorboard_scalars_under_runs_and_from_tb_folder(logs: Path, tmp_path: Path):
    write_scalars(logs / "ppo" / f"{ENV}_1" / "tb", "reserve/team_reward", {100: 1.0, 200: 3.0})
    write_scalars(logs / "ppo" / f"{ENV}_2" / "tb", "reserve/team_reward", {100: 3.0, 200: 7.0})
    scalars = plots.read_scalars(logs / "ppo" / f"{ENV}_1")
    steps, hours, values = scalars["reserve/team_reward"]
    assert steps.tolist() == [100, 200] and values.tolist() == [1.0, 3.0] and (hours >= 0).all()
    figure = plots.build_figure(plots.plot_parser().parse_args(["-f", str(logs), "-k", "reserve/team_reward"]))
    x, y = line_data(figure)
    assert (x[0], x[-1]) == (100.0, 200.0)
    assert (y[0], y[-1]) == (2.0, 5.0)
    # The zoo's -tb layout: <tb>/<env>/PPO_<n>.
    write_scalars(tmp_path / "tb" / ENV / "PPO_1", "rollout/ep_rew_mean", {50: 4.0, 150: 6.0})
    figure = plots.build_figure(plots.plot_parser().parse_args(
        ["-f", str(logs), "-k", "rollout/ep_rew_mean", "-tb", str(tmp_path / "tb")]))
    assert line_data(figure)[1][[0, -1]].tolist() == [4.0, 6.0]
    assert [r.folder.name for r in plots.tensorboard_runs(tmp_path / "tb", plots.zoo_runs([logs]))] == ["PPO_1"]


def test_centralised_runs_count_agent_steps(tmp_path: Path):
    """A centralised run (cppo) writes one monitor row per team episode and counts SB3 timesteps in team steps: both
    become agent-steps (x the team's UAVs), as on the parameter-sharing view."""
    logs = tmp_path / "logs"
    write_monitor(logs / "cppo" / f"{ENV}_1", [1, 2, 3], n_uavs=1)  # one row per team episode
    (logs / "cppo" / f"{ENV}_1" / ENV / "config.yml").write_text("env_kwargs:\n  n_uavs: 3\n")
    (run,) = plots.zoo_runs([logs])
    assert (run.agents_per_copy, run.team_size, run.uav_steps_per_timestep) == (1, 3, 3)
    figure = plots.build_figure(plots.plot_parser().parse_args(["-f", str(logs), "-w", "1"]))
    assert line_data(figure)[0][[0, -1]].tolist() == [30.0, 90.0]  # 3 UAVs x 10 steps per team episode
    write_scalars(tmp_path / "tb" / ENV / "PPO_1", "reserve/team_reward", {100: 1.0, 200: 2.0})
    figure = plots.build_figure(plots.plot_parser().parse_args(
        ["-f", str(logs), "-k", "reserve/team_reward", "-tb", str(tmp_path / "tb")]))
    assert line_data(figure)[0][[0, -1]].tolist() == [300.0, 600.0]


def test_seed_bars_keep_the_other_seeds_readable():
    figure = Figure()
    FigureCanvasAgg(figure)
    ax = figure.add_subplot()
    drawn = plots.seed_bars(ax, {"a2c": [-20, -22, -18, -1300, -25], "ppo": [5, 6, 7]}, ylabel="team reward")
    assert drawn.medians == {"a2c": -22.0, "ppo": 6.0}
    assert drawn.quartiles == {"a2c": (-25.0, -20.0), "ppo": (5.5, 6.5)}
    assert drawn.clipped == {"a2c": [-1300.0], "ppo": []}
    low, high = ax.get_ylim()
    assert -40 < low < -25 and 7 < high < 15  # the outlier does not flatten the others' 32-wide range
    assert [round(p.get_height(), 6) for p in ax.patches] == [-22.0, 6.0]
    assert [text.get_text() for text in ax.texts] == ["-1300"]  # the outlier's value, at its arrow
    assert drawn.ylim == (low, high)
    with pytest.raises(ValueError, match=r"positions has no x for the arm\(s\) \['ppo'\]"):
        plots.seed_bars(ax, {"a2c": [1.0], "ppo": [2.0]}, positions={"a2c": 0.0})
    with pytest.raises(ValueError, match="arm 'a2c': seed_bars needs at least one value, all finite"):
        plots.seed_bars(ax, {"a2c": [1.0, float("nan")]})


def test_readable_limits():
    # Three seeds, one collapsed: the median stays, the outlier goes.
    low, high, clipped = plots.readable_limits([-20, -18, -1300], keep=[-20, 0])
    assert (low, high) == (-20, 0) and clipped.tolist() == [False, False, True]
    # An ordinary spread is left whole (60 away from a range of 40: the rest keep 40 % of the axis).
    low, high, clipped = plots.readable_limits([10, 20, 30, 40, 100], keep=[30, 0])
    assert (low, high) == (0, 100) and not clipped.any()
    # Outliers at both ends, and a pair of them together.
    values = [-1300, -1250, -25, -20, 5, 7, 900]
    low, high, clipped = plots.readable_limits(values, keep=[-20, 5, 0])
    assert (low, high) == (-25, 7) and clipped.tolist() == [True, True, False, False, False, False, True]
    # A median is never clipped.
    low, high, clipped = plots.readable_limits([-1300, -1200, -1250, 5, 6], keep=[-1250, 5, 0])
    assert low == -1300 and not clipped.any()
    with pytest.raises(ValueError, match="min_share must be in"):
        plots.readable_limits([1, 2], keep=[0], min_share=1.5)


def test_bars_from_the_command_line(logs: Path, tmp_path: Path):
    write_monitor(logs / "ppo" / f"{ENV}_3", [-500, -500, -500, -500], n_uavs=2)
    write_monitor(logs / "a2c" / f"{ENV}_1", [0, 1, 1, 1], n_uavs=2)
    args = plots.plot_parser().parse_args(["-f", str(logs), "-w", "2", "--bars"])
    figure = plots.build_figure(args)
    ax = figure.axes[0]
    heights = sorted(round(p.get_height(), 6) for p in ax.patches)
    assert heights == [1.0, 3.5]  # a2c's final mean 1; ppo's median of 3.5, 5.5, -500
    assert ax.get_ylim()[0] > -10  # -500 drawn as an arrow at the edge
    assert [t.get_text() for t in ax.get_xticklabels()] == ["a2c", "ppo"]
    assert plots.main(["-f", str(logs), "-w", "2", "--bars", "-o", str(tmp_path / "bars.png")]) == 0
    assert (tmp_path / "bars.png").stat().st_size > 0


@pytest.mark.parametrize(("argv", "message"), [
    (["-f", "{tmp}/none"], "no runs of any algorithm on any environment under {tmp}/none"),
    (["-f", "{logs}", "-a", "dqn"], "no runs of dqn on any environment"),
    (["-f", "{logs}", "-k", "rewards"], "unknown key 'rewards': reward or length (the monitor files), and these runs "
                                        "have no tensorboard event files"),
    (["-f", "{logs}", "-x", "episodes"], "argument -x/--x-axis: invalid choice: 'episodes' (choose from 'steps', "
                                         "'time')"),
    (["-f", "{logs}", "-a", "ppo_x"], "argument -a/--algo/--algos: invalid choice: 'ppo_x'"),
    (["-f", "{logs}", "-o", "{tmp}/fig.jpg"], "the extension decides the format, one of .png, .pdf, .svg"),
    (["-f", "{logs}", "-w", "5"], "has 4 team episodes, fewer than -w/--episode-window 5: give -w 4 or less"),
    (["-f", "{logs}", "-w", "0"], "argument -w/--episode-window: must be an int in [1, 1000000], got 0"),
    (["-f", "{logs}", "-k", "x/y", "-tb", "{tmp}/tb"], "no tensorboard runs (PPO_<n>) under {tmp}/tb/ZonePatrol-v0"),
])
def test_bad_input_fails_with_one_line(logs: Path, tmp_path: Path, capsys, argv: list[str], message: str):
    with pytest.raises(SystemExit) as stopped:
        plots.main([a.format(tmp=tmp_path, logs=logs) for a in argv])
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("emmarl plot: error: ")
    assert message.format(tmp=tmp_path) in err


def test_unknown_key_lists_the_runs_tags(logs: Path, capsys):
    write_scalars(logs / "ppo" / f"{ENV}_1" / "tb", "reserve/team_reward", {100: 1.0})
    with pytest.raises(SystemExit):
        plots.main(["-f", str(logs), "-k", "reserve/team"])
    assert ("unknown key 'reserve/team': reward or length (the monitor files), or a tensorboard scalar of these runs: "
            "reserve/team_reward") in capsys.readouterr().err


def test_runs_of_one_tensorboard_name_are_refused(logs: Path, tmp_path: Path, capsys):
    write_monitor(logs / "oracle_ppo" / f"{ENV}_1", [1, 2, 3, 4], n_uavs=2)
    with pytest.raises(SystemExit):
        plots.main(["-f", str(logs), "-k", "rollout/ep_rew_mean", "-tb", str(tmp_path / "tb")])
    assert "oracle_ppo and ppo both write their tensorboard runs as PPO_<n>" in capsys.readouterr().err


def test_several_environments_need_env(logs: Path, capsys):
    write_monitor(logs / "ppo" / "WildlifeReserve-v1_1", [1, 2], n_uavs=10)
    with pytest.raises(SystemExit):
        plots.main(["-f", str(logs)])
    assert "runs of several environments under" in capsys.readouterr().err
    figure = plots.build_figure(plots.plot_parser().parse_args(["-f", str(logs), "-e", ENV, "-w", "1"]))
    assert figure.axes[0].get_title().startswith(ENV)


def test_missing_matplotlib_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(ModuleNotFoundError, match=r"pip install 'sb3-emmarl\[zoo\]'"):
        plots._require_matplotlib()


def test_module_entry_point():
    done = subprocess.run([sys.executable, "-m", "sb3_emmarl.plots", "--help"], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0 and "--episode-window" in done.stdout


def test_a_huge_figure_is_refused_before_drawing(capsys):
    from sb3_emmarl.plots import main

    with pytest.raises(SystemExit) as stop:
        main(["--figsize", "100000", "4", "-o", "never.png"])
    assert stop.value.code == 2 and "--figsize: must be a number in [1.0, 60.0], got 100000" in capsys.readouterr().err
