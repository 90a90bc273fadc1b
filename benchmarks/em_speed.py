"""Wall time of EM-PPO against PPO and RecurrentPPO at equal agent-steps, taking turns in one process.

Each algorithm is built from its zoo YAML (``em_ppo.yml``, ``ppo.yml``, ``ppo_lstm.yml``: the same PPO
settings) on the default reserve and trains ``-n`` agent-steps; the algorithms take turns, ``--rounds``
times (fresh models, seeds 0, 1, ...), with one torch thread, so that the machine's load drifts hit all
of them alike. The table gives the median seconds and agent-steps per second of each, and the ratios of
EM-PPO's median to the others'. ``--belief-conditioning film mixture`` adds turns of EM-PPO and told PPO
(``oracle_ppo``) whose networks read the belief or the told mode so (``policy_kwargs["belief_conditioning"]``), and the
ratio of each to the same algorithm's concatenation (issue 67's wall-time bar). Each turn is timed by phase too
(:class:`~sb3_emmarl.common.phases.PhaseTimes`): the median seconds of each phase per algorithm, and its wall time over
its floor (its policy's forward passes and its gradient epochs).

Example: ``python benchmarks/em_speed.py`` (or ``make benchmark-em-speed``; about 15 minutes); ``python
benchmarks/em_speed.py --algos em_ppo --belief-conditioning concat film mixture``
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import torch as th

from sb3_emmarl.common.centralized import ENV_ID
from sb3_emmarl.common.phases import FLOOR, PHASES, PhaseTimes
from sb3_emmarl.common.trust.validation import CONDITIONINGS, parse_policy_kwargs
from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.zoo.algos import ZOO_ALGOS
from sb3_emmarl.zoo.exp_manager import zoo_hyperparams, zoo_model


def zoo_settings(algo: str) -> dict:
    """The zoo YAML's settings of ``algo`` on the reserve."""
    settings = zoo_hyperparams(algo, ENV_ID)
    if settings.get("normalize"):
        raise ValueError(f"{algo}.yml normalizes observations; this benchmark does not")
    return settings


#: The phases' names in the table's columns.
SHORT = {"environment": "env", "policy forward": "forward", "gradient epochs": "gradients", "evaluation": "eval",
         "checkpoints": "ckpt"}
#: The algorithms whose policies take ``belief_conditioning``.
CONDITIONED = ("em_ppo", "oracle_ppo")


def build(algo: str, seed: int, env=None, vec_env_type: str | None = None, num_cpus: int = 0,
          n_copies: int | None = None, belief_conditioning: str = "concat"):
    """The algorithm with its zoo YAML's settings on ``n_envs`` (or ``n_copies``) default reserves (through
    ``vec_env_type``, in ``num_cpus`` processes), or on ``env``; its networks reading the belief or the told mode as
    ``belief_conditioning`` says."""
    settings = zoo_settings(algo)
    if env is None:
        env = make_vec_env(n_copies=int(n_copies or settings["n_envs"]), seed=seed,
                           env_kwargs=settings.get("env_kwargs") or {}, vec_env_type=vec_env_type, num_cpus=num_cpus)
    if belief_conditioning == "concat":
        return zoo_model(algo, env, seed)
    policy_kwargs = {**parse_policy_kwargs(settings.get("policy_kwargs")), "belief_conditioning": belief_conditioning}
    return zoo_model(algo, env, seed, policy_kwargs=policy_kwargs)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-n", "--n-timesteps", type=int, default=100_000, help="agent-steps per turn")
    parser.add_argument("--rounds", type=int, default=3, help="turns of each algorithm")
    parser.add_argument("--algos", nargs="+", default=["em_ppo", "ppo", "ppo_lstm"], choices=sorted(ZOO_ALGOS))
    parser.add_argument("--belief-conditioning", nargs="+", default=["concat"], choices=list(CONDITIONINGS),
                        help=f"how {' and '.join(CONDITIONED)} read the belief or the told mode (one turn each)")
    args = parser.parse_args(argv)
    if args.n_timesteps < 1 or args.rounds < 1:
        parser.error(f"-n and --rounds must be >= 1, got {args.n_timesteps} and {args.rounds}")
    th.set_num_threads(1)
    arms = [(algo, conditioning) for algo in args.algos
            for conditioning in (dict.fromkeys(["concat", *args.belief_conditioning]) if algo in CONDITIONED else ["concat"])]
    seconds: dict[str, list[float]] = {arm_name(*arm): [] for arm in arms}
    cpu: dict[str, list[float]] = {arm_name(*arm): [] for arm in arms}
    phases: dict[str, list[dict[str, float]]] = {arm_name(*arm): [] for arm in arms}
    for round_ in range(args.rounds):
        for algo, conditioning in arms:
            model = build(algo, seed=round_, belief_conditioning=conditioning)
            times = PhaseTimes()
            start, start_cpu = time.perf_counter(), time.process_time()
            model.learn(args.n_timesteps, callback=times)
            name = arm_name(algo, conditioning)
            seconds[name].append(time.perf_counter() - start)
            cpu[name].append(time.process_time() - start_cpu)
            phases[name].append(times.seconds)
            print(f"round {round_} {name}: {seconds[name][-1]:.1f} s ({cpu[name][-1]:.1f} s of CPU)", flush=True)
    print(f"\n{args.n_timesteps:,} agent-steps per turn, {args.rounds} turns each, one process, one torch thread "
          "(CPU: this process's CPU seconds, which other processes on the machine do not stretch)")
    print(f"{'algo':<20}{'median s':>10}{'agent-steps/s':>15}{'median CPU s':>14}")
    for name, values in seconds.items():
        print(f"{name:<20}{np.median(values):>10.1f}{args.n_timesteps / np.median(values):>15,.0f}"
              f"{np.median(cpu[name]):>14.1f}")

    print("\nmedian seconds per turn by phase (sb3_emmarl.common.phases; the floor: policy forward + gradient epochs)")
    shown = [phase for phase in PHASES if any(p[phase] > 0 for runs in phases.values() for p in runs)]
    print(f"{'algo':<20}" + "".join(f"{SHORT.get(phase, phase):>11}" for phase in shown) + f"{'wall/floor':>12}")
    for name, runs in phases.items():
        medians = {phase: float(np.median([p[phase] for p in runs])) for phase in shown}
        floor = float(np.median([sum(p[f] for f in FLOOR) for p in runs]))
        print(f"{name:<20}" + "".join(f"{medians[phase]:>11.2f}" for phase in shown)
              + f"{np.median(seconds[name]) / floor:>12.2f}")

    def ratio(a: str, b: str) -> str:
        return (f"{a} / {b}: {np.median(seconds[a]) / np.median(seconds[b]):.2f} "
                f"(CPU {np.median(cpu[a]) / np.median(cpu[b]):.2f})")

    if "em_ppo" in seconds:
        for other in (a for a in seconds if "+" not in a and a != "em_ppo"):
            print(ratio("em_ppo", other))
    for algo, conditioning in arms:
        if conditioning != "concat":
            print(ratio(arm_name(algo, conditioning), algo))
    return 0


def arm_name(algo: str, conditioning: str) -> str:
    return algo if conditioning == "concat" else f"{algo}+{conditioning}"


if __name__ == "__main__":
    sys.exit(main())
