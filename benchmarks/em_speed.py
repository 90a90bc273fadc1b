"""Wall time of EM-PPO against PPO and RecurrentPPO at equal agent-steps, taking turns in one process.

Each algorithm is built from its zoo YAML (``em_ppo.yml``, ``ppo.yml``, ``ppo_lstm.yml``: the same PPO
settings; ``mappo.yml`` its own) on the default reserve, or on ``--env`` (``ZonePatrol-v1``), and trains ``-n``
agent-steps; the algorithms take turns, ``--rounds``
times (fresh models, seeds 0, 1, ...), with one torch thread, so that the machine's load drifts hit all
of them alike. The table gives the median seconds and agent-steps per second of each, and the ratios of
EM-PPO's median to the others'. ``--belief-conditioning film mixture`` adds turns of EM-PPO and told PPO
(``oracle_ppo``) whose networks read the belief or the told mode so (``policy_kwargs["belief_conditioning"]``), and the
ratio of each to the same algorithm's concatenation (issue 67's wall-time bar). Each turn is timed by phase too
(:class:`~sb3_emmarl.common.phases.PhaseTimes`): the median seconds of each phase per algorithm, and its wall time over
its floor (its policy's forward passes and its gradient epochs).

Example: ``python benchmarks/em_speed.py`` (or ``make benchmark-em-speed``; about 15 minutes); ``python
benchmarks/em_speed.py --algos em_ppo --belief-conditioning concat film mixture``; ``python benchmarks/em_speed.py
--env ZonePatrol-v1 --algos em_ppo ppo mappo``
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch as th

from sb3_emmarl.common.centralized import ENV_ID
from sb3_emmarl.common.env_ids import ENV_MODULES, parallel_env_fn
from sb3_emmarl.common.phases import PhaseTimes, machine_load, median_phase_table
from sb3_emmarl.common.trust.arguments import json_object
from sb3_emmarl.common.trust.validation import CONDITIONINGS
from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.zoo.algos import STATE_ALGOS, ZOO_ALGOS
from sb3_emmarl.zoo.exp_manager import zoo_hyperparams, zoo_model, zoo_policy_kwargs


def zoo_settings(algo: str, env_id: str = ENV_ID) -> dict:
    """The zoo YAML's settings of ``algo`` on ``env_id``."""
    settings = zoo_hyperparams(algo, env_id)
    if settings.get("normalize"):
        raise ValueError(f"{algo}.yml normalizes observations on {env_id}; this benchmark does not")
    return settings


#: The algorithms whose policies take ``belief_conditioning``.
CONDITIONED = ("em_ppo", "oracle_ppo")


def build(algo: str, seed: int, env=None, vec_env_type: str | None = None, num_cpus: int = 0,
          n_copies: int | None = None, belief_conditioning: str = "concat", env_id: str = ENV_ID,
          env_kwargs: dict | None = None):
    """The algorithm with its zoo YAML's settings on ``n_envs`` (or ``n_copies``) copies of ``env_id`` (through
    ``vec_env_type``, in ``num_cpus`` processes; the global state in the infos for MAPPO and QMIX; ``env_kwargs`` laid
    over the YAML's), or on ``env``; its networks reading the belief or the told mode as ``belief_conditioning`` says."""
    settings = zoo_settings(algo, env_id)
    if env is None:
        env = make_vec_env(n_copies=int(n_copies or settings["n_envs"]), seed=seed,
                           env_kwargs={**(settings.get("env_kwargs") or {}), **(env_kwargs or {})},
                           vec_env_type=vec_env_type or "batched",
                           num_cpus=num_cpus, env_fn=parallel_env_fn(env_id), with_state=algo in STATE_ALGOS)
    if belief_conditioning == "concat":
        return zoo_model(algo, env, seed, env_id)
    return zoo_model(algo, env, seed, env_id,
                     policy_kwargs=zoo_policy_kwargs(algo, env_id, belief_conditioning=belief_conditioning))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-n", "--n-timesteps", type=int, default=100_000, help="agent-steps per turn")
    parser.add_argument("--rounds", type=int, default=3, help="turns of each algorithm")
    parser.add_argument("--env", default=ENV_ID, choices=sorted(ENV_MODULES), help="the task every turn trains on")
    parser.add_argument("--env-kwargs", type=json_object, default={},
                        help="the task's arguments over the YAML's, as a JSON object, e.g. "
                             "'{\"scenario\": \"zone_raids\", \"shaping\": 0.5}'")
    parser.add_argument("--algos", nargs="+", default=["em_ppo", "ppo", "ppo_lstm"], choices=sorted(ZOO_ALGOS))
    parser.add_argument("--belief-conditioning", nargs="+", default=["concat"], choices=list(CONDITIONINGS),
                        help=f"how {' and '.join(CONDITIONED)} read the belief or the told mode (one turn each)")
    args = parser.parse_args(argv)
    if args.n_timesteps < 1 or args.rounds < 1:
        parser.error(f"-n and --rounds must be >= 1, got {args.n_timesteps} and {args.rounds}")
    th.set_num_threads(1)
    load = machine_load()
    arms = [(algo, conditioning) for algo in args.algos
            for conditioning in (dict.fromkeys(["concat", *args.belief_conditioning]) if algo in CONDITIONED else ["concat"])]
    seconds: dict[str, list[float]] = {arm_name(*arm): [] for arm in arms}
    cpu: dict[str, list[float]] = {arm_name(*arm): [] for arm in arms}
    phases: dict[str, list[dict[str, float]]] = {arm_name(*arm): [] for arm in arms}
    for round_ in range(args.rounds):
        for algo, conditioning in arms:
            model = build(algo, seed=round_, belief_conditioning=conditioning, env_id=args.env, env_kwargs=args.env_kwargs)
            times = PhaseTimes()
            start, start_cpu = time.perf_counter(), time.process_time()
            model.learn(args.n_timesteps, callback=times)
            name = arm_name(algo, conditioning)
            seconds[name].append(time.perf_counter() - start)
            cpu[name].append(time.process_time() - start_cpu)
            phases[name].append(times.seconds)
            print(f"round {round_} {name}: {seconds[name][-1]:.1f} s ({cpu[name][-1]:.1f} s of CPU)", flush=True)
    print(f"\n{args.env} {json.dumps(args.env_kwargs)}: {args.n_timesteps:,} agent-steps per turn, {args.rounds} turns "
          "each, one process, one torch thread "
          "(CPU: this process's CPU seconds, which other processes on the machine do not stretch)")
    end = machine_load()
    print(f"the machine's load average: {load['load_1min']:.1f} at the start, {end['load_1min']:.1f} at the end "
          f"({end['cores']:.0f} cores)")
    print(f"{'algo':<20}{'median s':>10}{'agent-steps/s':>15}{'median CPU s':>14}")
    for name, values in seconds.items():
        print(f"{name:<20}{np.median(values):>10.1f}{args.n_timesteps / np.median(values):>15,.0f}"
              f"{np.median(cpu[name]):>14.1f}")

    print("\n" + median_phase_table(phases, seconds))

    def ratio(a: str, b: str) -> str:
        return (f"{a} / {b}: {np.median(seconds[a]) / np.median(seconds[b]):.2f} "
                f"(CPU {np.median(cpu[a]) / np.median(cpu[b]):.2f})")

    if "ppo" in seconds:  # (issue 68's bars: EM-PPO and MAPPO against PPO)
        for name in (a for a in seconds if "+" not in a and a != "ppo"):
            print(ratio(name, "ppo"))
    if "em_ppo" in seconds:
        for other in (a for a in seconds if "+" not in a and a not in ("em_ppo", "ppo")):
            print(ratio("em_ppo", other))
    for algo, conditioning in arms:
        if conditioning != "concat":
            print(ratio(arm_name(algo, conditioning), algo))
    return 0


def arm_name(algo: str, conditioning: str) -> str:
    return algo if conditioning == "concat" else f"{algo}+{conditioning}"


if __name__ == "__main__":
    sys.exit(main())
