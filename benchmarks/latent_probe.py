"""How much of the reserve's hidden mode is in what the latent encoder reads: a supervised ceiling.

EM never sees the mode; its posterior can only be as informative as the history window it reads.
This script measures that ceiling directly: it plays random-action episodes through the
parameter-sharing vector environment with a :class:`~sb3_emmarl.common.latent.history.HistoryWrapper`,
then trains a small classifier *with the true mode as label* to predict the mode (and its two parts,
poacher strategy and weather) from each agent-step's history window, and from the window plus the
current observation. It prints held-out accuracies beside the majority-class rate. A latent accuracy
(``evaluate_team``'s ``latent_accuracy``) near the window's row is as good as the window allows; a
window row near the majority rate means the mode is not in the window, whatever the E-step does.

Agent-steps earlier in their episode than ``H`` are left out, as in ``evaluate_team``.

Example: ``python benchmarks/latent_probe.py --history-lengths 8 32`` (or ``make benchmark-latent-probe``)
"""

from __future__ import annotations

import argparse

import numpy as np
import torch as th
from torch import nn

from sb3_emmarl.common.latent.history import HistoryWrapper
from sb3_emmarl.common.vec_env import make_vec_env
from wildlife_reserve.reserve.modes import N_MODES, WEATHERS


def collect(history_length: int, n_steps: int, n_copies: int, seed: int, env_kwargs: dict | None = None):
    """Random-action agent-steps: augmented observations, true modes and steps since the episode began.

    :return: ``(observations (N, total_dim), modes (N,), steps (N,), layout)``; the mode is -1 where not yet
        known (an episode's first observation: the mode arrives in the infos of its first step)
    """
    venv = HistoryWrapper(make_vec_env(n_copies, seed=seed, env_kwargs=env_kwargs), history_length=history_length)
    venv.action_space.seed(seed)
    rng = np.random.default_rng(seed)
    n = venv.num_envs
    obs = venv.reset()
    mode, step = np.full(n, -1), np.zeros(n, dtype=np.int64)
    observations, modes, steps = [], [], []
    for _ in range(n_steps):
        observations.append(obs)
        modes.append(mode.copy())
        steps.append(step.copy())
        obs, _, dones, infos = venv.step(rng.integers(0, venv.action_space.n, n))
        mode = np.array([info.get("mode", -1) for info in infos])
        mode[dones] = -1  # the next observation starts a new episode whose mode is not known yet
        step = np.where(dones, 0, step + 1)
    venv.close()
    return np.concatenate(observations), np.concatenate(modes), np.concatenate(steps), venv.layout


def probe_accuracy(train_x: np.ndarray, train_y: np.ndarray, test_x: np.ndarray, n_classes: int, epochs: int,
                   seed: int) -> np.ndarray:
    """Predicted classes for ``test_x`` from an MLP (128 ReLU units) trained by cross-entropy on standardised inputs."""
    th.manual_seed(seed)
    x = th.as_tensor(train_x, dtype=th.float32)
    y = th.as_tensor(train_y, dtype=th.long)
    mean, std = x.mean(0), x.std(0) + 1e-6
    net = nn.Sequential(nn.Linear(x.shape[1], 128), nn.ReLU(), nn.Linear(128, n_classes))
    optimizer = th.optim.Adam(net.parameters(), lr=1e-3)
    for _ in range(epochs):
        order = th.randperm(len(x))
        for start in range(0, len(x), 512):
            idx = order[start:start + 512]
            loss = nn.functional.cross_entropy(net((x[idx] - mean) / std), y[idx])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    with th.no_grad():
        return net((th.as_tensor(test_x, dtype=th.float32) - mean) / std).argmax(1).numpy()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--history-lengths", type=int, nargs="+", default=[8, 32], help="window lengths H")
    parser.add_argument("--train-steps", type=int, default=3840, help="vector steps of training data")
    parser.add_argument("--test-steps", type=int, default=1024, help="vector steps of held-out data (other seed)")
    parser.add_argument("--n-copies", type=int, default=4, help="reserve copies (10 UAVs each by default)")
    parser.add_argument("--epochs", type=int, default=15, help="classifier epochs")
    parser.add_argument("--seed", type=int, default=0, help="seed of the training episodes (held-out: seed + 1)")
    args = parser.parse_args(argv)
    if min(args.history_lengths) < 1 or min(args.train_steps, args.test_steps, args.n_copies, args.epochs) < 1:
        parser.error("history lengths, steps, copies and epochs must be >= 1")
    th.set_num_threads(1)
    n_weathers = len(WEATHERS)
    print("Held-out accuracy of a supervised probe (random-action episodes); chance: majority class of the held-out set")
    print(f"{'H':>4} {'input':<18}{'mode':>8}{'strategy':>10}{'weather':>9}{'majority':>10}{'agent-steps':>13}")
    for history_length in args.history_lengths:
        train_obs, train_modes, train_steps, layout = collect(history_length, args.train_steps, args.n_copies, args.seed)
        test_obs, test_modes, test_steps, _ = collect(history_length, args.test_steps, args.n_copies, args.seed + 1)
        train_keep = (train_steps >= history_length) & (train_modes >= 0)
        test_keep = (test_steps >= history_length) & (test_modes >= 0)
        truth = test_modes[test_keep]
        majority = np.bincount(truth).max() / len(truth)
        for name, columns in (("window", slice(layout.obs_dim, None)), ("window + obs", slice(None))):
            predicted = probe_accuracy(train_obs[train_keep][:, columns], train_modes[train_keep],
                                       test_obs[test_keep][:, columns], N_MODES, args.epochs,
                                       args.seed)
            mode = np.mean(predicted == truth)
            strategy = np.mean(predicted // n_weathers == truth // n_weathers)
            weather = np.mean(predicted % n_weathers == truth % n_weathers)
            print(f"{history_length:>4} {name:<18}{mode:>8.3f}{strategy:>10.3f}{weather:>9.3f}{majority:>10.3f}"
                  f"{int(train_keep.sum()):>13,}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
