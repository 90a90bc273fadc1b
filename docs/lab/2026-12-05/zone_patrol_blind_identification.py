"""How soon the best scripted blind team of ZonePatrol (``BlindTeam("split", "estimate")``: its UAVs share everything
they see) knows the mode: its zone estimate (the zone with evidence) and weather estimate (mean visibility reading above
one half) against the truth, at steps 10, 20, 30, 45 and 59 of 300 episodes. ``python
docs/lab/2026-12-05/zone_patrol_blind_identification.py``."""

import numpy as np

from wildlife_reserve.zone_patrol.scripted import BlindTeam
from wildlife_reserve.zone_patrol.world import CLEAR, ZonePatrolConfig, ZonePatrolWorld

STEPS = (10, 20, 30, 45, 59)


def main() -> None:
    cfg = ZonePatrolConfig.from_kwargs()
    world, team, rng = ZonePatrolWorld(cfg, 20), BlindTeam("split", "estimate"), np.random.default_rng(7)
    right: dict[str, dict[int, list[bool]]] = {part: {t: [] for t in STEPS} for part in ("mode", "zone", "weather")}
    for _ in range(15):
        world.reset(rng)
        team.reset(world)
        for t in range(cfg.max_cycles):
            world.step(team.act(world), rng)
            if t in STEPS:
                zone = np.where(team.evidence.max(1) > 0, team.evidence.argmax(1), -1) == world.zones
                weather = (team.readings / max(team.n_readings, 1) > 0.5) == (world.weathers == CLEAR)
                for part, ok in (("mode", zone & weather), ("zone", zone), ("weather", weather)):
                    right[part][t] += ok.tolist()
    for t in STEPS:
        print(f"step {t:2d}: " + ", ".join(f"{part} {np.mean(right[part][t]):.3f}" for part in right))


if __name__ == "__main__":
    main()
