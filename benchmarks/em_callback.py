"""EMCallback on ModeCueEnv: does an SB3 algorithm given the callback's belief approach the same algorithm told the mode?

The protocol, its bars and the results: docs/lab/2026-12-06/em_callback.md (written before the runs).

``gate`` trains no policy: it fits the callback's mixture by EM on random-action episodes (through the functions the
callback and EM-PPO share) and measures its belief's aligned accuracy on held-out episodes, and what scripted players
earn (told the mode, following each step's cue, acting on the exact posterior of the cues, a random label).
``run`` trains the arms one after the other in this process (one torch thread; a run already in ``--folder`` is kept):
``plain`` (the task as it is), ``told`` (``ModeCueEnv(told=True)``: the mode's one-hot appended), ``em`` (the
observation and the belief of an :class:`~sb3_emmarl.common.latent.callback.EMCallback`) and ``random`` (a one-hot of
a label drawn at random per episode appended: the same input form, no information). Each run is scored by SB3's
``evaluate_policy`` on the same ``--eval-episodes`` held-out episodes (4 copies seeded ``EVAL_SEED``), deterministic
and sampled actions; the ``em`` runs also with their belief permuted between components, and their belief's aligned
accuracy at mid-episode. ``report`` prints the table and the bars.

Example: ``python benchmarks/em_callback.py run --algo a2c --seeds 0 1 2 3 4 --folder logs/em_callback`` then
``python benchmarks/em_callback.py report --algo a2c --seeds 0 1 2 3 4 --folder logs/em_callback``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_emmarl.common.appended.wrapping import find_wrapper
from sb3_emmarl.common.statistics import paired_p_value, wilcoxon_p_value

#: Agent-steps per run of each algorithm (every arm alike), fixed in the protocol.
BUDGETS = {"a2c": 50_000, "dqn": 30_000}
#: Vector copies each algorithm trains on (SB3's ``make_vec_env``).
N_ENVS = {"a2c": 8, "dqn": 1}
ARMS = ("plain", "told", "em", "random")
#: Seed of the held-out evaluation episodes (far from the training seeds; the same for every run).
EVAL_SEED = 10_000
#: The protocol's bars: EMCallback's return over told's; plain's and the control's distance from the cue-following
#: level; the collapse rule (a run below the cue-following level by this much).
TARGET, PLAIN_MARGIN, COLLAPSE_MARGIN = 0.8, 1.0, 3.0


class RandomLabel(gym.ObservationWrapper):
    """Append the one-hot of a label drawn uniformly at random at each reset (independent of the mode).

    :param env: a hidden-mode task
    :param n_labels: labels (the one-hot's length)
    :param seed: seed of the labels
    """

    def __init__(self, env: gym.Env, n_labels: int, seed: int) -> None:
        super().__init__(env)
        space = env.observation_space
        assert isinstance(space, gym.spaces.Box)  # (the tasks' observations are flat boxes in [-1, 1])
        self.n_labels, self.rng, self.label = n_labels, np.random.default_rng(seed), 0
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (space.shape[0] + n_labels,), np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        self.label = int(self.rng.integers(self.n_labels))
        return super().reset(**kwargs)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return np.concatenate([observation, np.eye(self.n_labels, dtype=np.float32)[self.label]])


def task_env(arm: str, n_envs: int, seed: int):
    """The vector environment an arm trains or is scored on (the ``em`` arm's without its belief yet)."""
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_emmarl.common.mode_tasks import ModeCueEnv

    if arm == "told":
        return make_vec_env(ModeCueEnv, n_envs=n_envs, seed=seed, env_kwargs={"told": True})
    if arm == "random":
        return make_vec_env(ModeCueEnv, n_envs=n_envs, seed=seed, wrapper_class=RandomLabel,
                            wrapper_kwargs={"n_labels": ModeCueEnv().n_modes, "seed": seed})
    return make_vec_env(ModeCueEnv, n_envs=n_envs, seed=seed)


def belief_accuracy(callback, policy, episodes: int, seed: int) -> float:
    """Aligned accuracy of the callback's belief at each episode's middle step, on ``episodes`` episodes of ``policy``
    (a function of the augmented observations; None: random actions) from seed ``seed``."""
    from sb3_emmarl.common.latent.metrics import align_components

    venv = callback.wrap_env(task_env("plain", 4, seed))
    obs, steps, rng = venv.reset(), np.zeros(4, dtype=np.int64), np.random.default_rng(seed)
    middle = venv.get_attr("length")[0] // 2
    beliefs, modes = [], []
    while len(modes) < episodes:
        at = np.flatnonzero(steps == middle)
        if len(at):
            current = np.array(venv.get_attr("mode"))
            beliefs += list(obs[at, -callback.layout.n_components:])
            modes += list(current[at])
        actions = rng.integers(venv.action_space.n, size=4) if policy is None else policy(obs)
        obs, _, dones, _ = venv.step(actions)
        steps = np.where(dones, 0, steps + 1)
    beliefs_array, modes_array = np.array(beliefs[:episodes]), np.array(modes[:episodes])
    mapping = align_components(beliefs_array, modes_array)
    return float((mapping[beliefs_array.argmax(1)] == modes_array).mean())


def gate(episodes: int, fit_episodes: int, seed: int = 0) -> dict:
    """The gate of the protocol: the fitted mixture's belief on held-out episodes, and the scripted players' returns."""
    import torch as th
    from stable_baselines3.common.logger import Logger

    from sb3_emmarl.common.latent.algorithm import augmented_features, e_step_and_log, make_transitions
    from sb3_emmarl.common.latent.belief import BeliefWrapper
    from sb3_emmarl.common.latent.callback import EMCallback
    from sb3_emmarl.common.mode_tasks import ModeCueEnv

    th.set_num_threads(1)
    callback = EMCallback(seed=seed)
    venv = callback.wrap_env(task_env("plain", 8, seed))
    wrapper, rng = find_wrapper(venv, BeliefWrapper), np.random.default_rng(seed)
    obs, rows = venv.reset(), []
    for _ in range(fit_episodes * ModeCueEnv().length // 8):  # random-action episodes, every copy's
        actions = rng.integers(4, size=8)
        next_obs, _, dones, infos = venv.step(actions)
        following = np.array([info["terminal_observation"] if done else o for o, done, info in zip(next_obs, dones, infos)])
        rows.append((obs, actions, following, dones))
        obs = next_obs
    observations, actions, following, dones = (np.stack(x) for x in zip(*rows))
    starts = np.concatenate([np.ones((1, 8), bool), dones[:-1]])
    features = augmented_features(wrapper.feature_fn, observations, callback.layout.obs_dim)
    next_features = augmented_features(wrapper.feature_fn, following, callback.layout.obs_dim)
    data = make_transitions(features, actions, next_features, starts, np.ones_like(dones), np.zeros(8, np.int64),
                            wrapper.encode_action)
    callback.e_step.add(*data)
    for _ in range(10):  # ten E-steps on the same episodes: batch EM
        e_step_and_log(callback.e_step, Logger(None, []))
    accuracy = belief_accuracy(callback, None, episodes, EVAL_SEED)
    env = ModeCueEnv()
    returns = {name: [] for name in ("told", "cue", "posterior", "random_label")}
    for episode in range(episodes):
        cue, _ = env.reset(seed=EVAL_SEED + episode)
        log_post, label, done = np.zeros(env.n_modes), int(rng.integers(env.n_modes)), False
        totals = dict.fromkeys(returns, 0.0)
        right = env.cue_accuracy + (1 - env.cue_accuracy) / env.n_modes
        while not done:
            log_post += np.log(np.where(cue > 0.5, right, (1 - right) / (env.n_modes - 1)))
            choices = {"told": env.mode, "cue": int(cue.argmax()), "posterior": int(log_post.argmax()),
                       "random_label": label}
            for name, action in choices.items():
                totals[name] += float(action == env.mode)
            cue, _, terminated, truncated, _ = env.step(0)
            done = terminated or truncated
        for name in returns:
            returns[name].append(totals[name])
    return {"belief_accuracy_mid": accuracy, **{name: float(np.mean(v)) for name, v in returns.items()}}


def run(algo: str, arm: str, seed: int, budget: int, eval_episodes: int) -> dict:
    """Train one arm of one algorithm on one seed and score it."""
    import torch as th
    from stable_baselines3 import A2C, DQN
    from stable_baselines3.common.evaluation import evaluate_policy

    from sb3_emmarl.common.latent.callback import EMCallback
    from sb3_emmarl.common.latent.diagnostics import permute_beliefs

    th.set_num_threads(1)
    algo_class = {"a2c": A2C, "dqn": DQN}[algo]
    env = task_env(arm, N_ENVS[algo], seed)
    callback, kwargs = None, {}
    if arm == "em":
        callback = EMCallback(seed=seed)
        env = callback.wrap_env(env)
        kwargs["policy_kwargs"] = callback.policy_kwargs
    model = algo_class("MlpPolicy", env, seed=seed, **kwargs)
    from sb3_emmarl.common.phases import PhaseTimes, machine_load

    times, load = PhaseTimes([] if callback is None else [callback]), machine_load()
    start = time.perf_counter()
    model.learn(budget, callback=times)
    seconds = time.perf_counter() - start

    def scored(deterministic: bool, permuted: bool = False) -> float:
        venv = task_env(arm, 4, EVAL_SEED)
        if callback is not None:
            venv = callback.wrap_env(venv)
        policy = model
        if permuted:
            k = callback.layout.n_components

            class Permuted:  # the model, acting on beliefs moved one component on
                @staticmethod
                def predict(obs, state=None, episode_start=None, deterministic=True):
                    return model.predict(permute_beliefs(obs, k), state, episode_start, deterministic)

            policy = Permuted()
        return float(evaluate_policy(policy, venv, n_eval_episodes=eval_episodes, deterministic=deterministic)[0])

    record = {"algo": algo, "arm": arm, "seed": seed, "budget": budget, "eval_episodes": eval_episodes,
              "seconds": seconds, "phase_seconds": times.seconds, "load": {"start": load, "end": machine_load()},
              "return": scored(True), "return_sampled": scored(False)}
    if callback is not None:
        record["return_permuted"] = scored(True, permuted=True)
        record["belief_accuracy_mid"] = belief_accuracy(
            callback, lambda obs: model.predict(obs, deterministic=True)[0], 200, EVAL_SEED)
    return record


#: The settings each algorithm's report names (every arm takes SB3's defaults of them).
SETTINGS = {"a2c": ("learning_rate", "n_steps", "gamma", "gae_lambda", "ent_coef", "vf_coef"),
            "dqn": ("learning_rate", "buffer_size", "learning_starts", "batch_size", "train_freq",
                    "target_update_interval", "exploration_fraction", "exploration_final_eps")}


def algo_settings(algo: str) -> str:
    """``algo``'s settings every arm trains with (SB3's defaults) and the callback's (its defaults), as a line."""
    import inspect

    from stable_baselines3 import A2C, DQN

    from sb3_emmarl.common.latent.callback import EMCallback

    parameters = inspect.signature({"a2c": A2C, "dqn": DQN}[algo].__init__).parameters
    every_arm = ", ".join(f"{name} {parameters[name].default}" for name in SETTINGS[algo])
    callback = EMCallback.latent_defaults.e_step_every
    return f"every arm: SB3's {algo.upper()} defaults ({every_arm}); em: EMCallback's defaults (e_step_every {callback})"


def run_file(folder: Path, algo: str, arm: str, seed: int) -> Path:
    return folder / f"{algo}_{arm}_{seed}.json"


def describe(values: np.ndarray) -> str:
    return f"{values.mean():7.2f} +- {values.std():5.2f} (median {np.median(values):6.2f})"


def report(algo: str, seeds: list[int], folder: Path, cue_level: float) -> str:
    """The protocol's table and bars for ``algo`` over ``seeds`` (every arm must be there)."""
    with warnings.catch_warnings():  # (scipy warns of pairs without spread: the arms that never vary, e.g. told at 32)
        warnings.simplefilter("ignore", RuntimeWarning)
        return _report(algo, seeds, folder, cue_level)


def _report(algo: str, seeds: list[int], folder: Path, cue_level: float) -> str:
    runs = {arm: {} for arm in ARMS}
    for arm in ARMS:
        for seed in seeds:
            path = run_file(folder, algo, arm, seed)
            if path.exists():
                runs[arm][seed] = json.loads(path.read_text())
    arms = [arm for arm in ARMS if len(runs[arm]) == len(seeds)]
    if not {"plain", "told", "em"} <= set(arms):
        raise SystemExit(f"{algo}: plain, told and em need every seed of {seeds} in {folder}")

    def values(arm: str, key: str = "return") -> np.ndarray:
        return np.array([runs[arm][s][key] for s in seeds])

    first = runs["told"][seeds[0]]
    lines = [f"{algo.upper()} on ModeCueEnv (defaults), {first['budget']:,} agent-steps, seeds {seeds}, "
             f"{first['eval_episodes']} held-out episodes (seed {EVAL_SEED}); cue-following level {cue_level:.2f}",
             f"  {algo_settings(algo)}",
             f"  {'arm':<16}{'deterministic':>36}{'sampled':>36}   per seed (deterministic)"]
    for arm in arms:
        lines.append(f"  {arm:<16}{describe(values(arm)):>36}{describe(values(arm, 'return_sampled')):>36}   "
                     + " ".join(f"{v:.2f}" for v in values(arm)))
    em, told, plain = values("em"), values("told"), values("plain")
    lines.append(f"  {'em, permuted':<16}{describe(values('em', 'return_permuted')):>36}")
    ratio, ratios = em.mean() / told.mean(), em / told
    lines.append(f"  em / told: {ratio:.3f} (bar {TARGET}: {'PASS' if ratio >= TARGET else 'FAIL'}); per seed "
                 + " ".join(f"{r:.2f}" for r in ratios) + f"; seeds at >= {TARGET}: {int((ratios >= TARGET).sum())} of "
                 f"{len(seeds)}")
    lines.append(f"  plain - cue level: {plain.mean() - cue_level:+.2f} (bar: within {PLAIN_MARGIN}: "
                 f"{'PASS' if abs(plain.mean() - cue_level) <= PLAIN_MARGIN else 'FAIL'})")
    for name, a, b in (("em - plain", em, plain), ("told - plain", told, plain),
                       ("em - em permuted", em, values("em", "return_permuted"))):
        lines.append(f"  {name}: {(a - b).mean():+.2f}, paired t p {paired_p_value(a, b):.3g}, Wilcoxon p "
                     f"{wilcoxon_p_value(a, b):.3g}, higher on {int((a > b).sum())} of {len(seeds)}")
    if "random" in arms:
        rand = values("random")
        lines.append(f"  random - plain: {(rand - plain).mean():+.2f}, paired t p {paired_p_value(rand, plain):.3g}; "
                     f"told - random: {(told - rand).mean():+.2f}, paired t p {paired_p_value(told, rand):.3g}, higher "
                     f"on {int((told > rand).sum())} of {len(seeds)}")
    accuracy = values("em", "belief_accuracy_mid")
    lines.append(f"  em's belief at mid-episode (aligned accuracy): {accuracy.mean():.3f} +- {accuracy.std():.3f}")
    collapsed = [f"{arm} seed {s}" for arm in arms for s in seeds if runs[arm][s]["return"] < cue_level - COLLAPSE_MARGIN
                 and arm != "random"]
    lines.append(f"  collapsed (return below {cue_level - COLLAPSE_MARGIN:.2f}): {', '.join(collapsed) or 'none'}")
    lines.append("  training seconds per run: " + ", ".join(f"{arm} {np.mean(values(arm, 'seconds')):.0f}" for arm in arms))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    gate_parser = commands.add_parser("gate", help="the fitted mixture's belief and the scripted players (no training)")
    gate_parser.add_argument("--episodes", type=int, default=200, help="held-out episodes")
    gate_parser.add_argument("--fit-episodes", type=int, default=125, help="random-action episodes EM is fitted on")
    for name, helptext in (("run", "train and score the runs missing from --folder"),
                           ("report", "the table of the runs in --folder")):
        sub = commands.add_parser(name, help=helptext)
        sub.add_argument("--algo", choices=list(BUDGETS), required=True)
        sub.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
        sub.add_argument("--folder", required=True)
        if name == "run":
            sub.add_argument("--arms", nargs="+", choices=list(ARMS), default=list(ARMS))
            sub.add_argument("--budget", type=int, default=None, help="agent-steps (default: the protocol's)")
            sub.add_argument("--eval-episodes", type=int, default=200)
    args = parser.parse_args(argv)
    from sb3_emmarl.common.mode_tasks import ModeCueEnv

    env = ModeCueEnv()
    cue_level = env.length * (env.cue_accuracy + (1 - env.cue_accuracy) / env.n_modes)
    if args.command == "gate":
        if args.episodes < 1 or args.fit_episodes < 8:
            parser.error("--episodes must be >= 1 and --fit-episodes >= 8")
        result = gate(args.episodes, args.fit_episodes)
        print(f"fitted mixture's belief at mid-episode, {args.episodes} held-out episodes of random actions: aligned "
              f"accuracy {result['belief_accuracy_mid']:.3f}")
        print(f"scripted players' return over {args.episodes} episodes: told {result['told']:.2f}, following the cue "
              f"{result['cue']:.2f} (expected {cue_level:.2f}), the cues' exact posterior {result['posterior']:.2f}, a "
              f"random label {result['random_label']:.2f}; told - cue {result['told'] - result['cue']:+.2f}")
        return 0
    if len(set(args.seeds)) != len(args.seeds) or min(args.seeds) < 0:
        parser.error("--seeds must be distinct and >= 0")
    folder = Path(args.folder)
    if args.command == "report":
        print(report(args.algo, args.seeds, folder, cue_level))
        return 0
    budget = BUDGETS[args.algo] if args.budget is None else args.budget
    if budget < 1 or args.eval_episodes < 1:
        parser.error("--budget and --eval-episodes must be >= 1")
    from sb3_emmarl.common.phases import load_title, phase_table
    from sb3_emmarl.common.trust.atomic_files import write_text
    from sb3_emmarl.version import __version__

    folder.mkdir(parents=True, exist_ok=True)
    for seed in args.seeds:
        for arm in args.arms:
            path = run_file(folder, args.algo, arm, seed)
            if path.exists():
                print(f"{path.name}: kept", flush=True)
                continue
            record = run(args.algo, arm, seed, budget, args.eval_episodes)
            write_text(path, json.dumps({**record, "version": __version__}))
            print(f"{path.name}: return {record['return']:.2f} (sampled {record['return_sampled']:.2f})"
                  + (f", permuted {record['return_permuted']:.2f}, belief {record['belief_accuracy_mid']:.3f}"
                     if arm == "em" else "") + f", {record['seconds']:.0f} s", flush=True)
            print(phase_table(record["phase_seconds"], record["seconds"],
                              load_title(record["load"]["start"], record["load"]["end"])), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
