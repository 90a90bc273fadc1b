#!/usr/bin/env bash
# The protocol of docs/zone_patrol.md ("The learned team on version 1"), in the order it was run: the four arms on seeds
# 0-9, the arms beside on seeds 0-4, the confirmation on seeds 10-19. Every run is a JSON record in the folders below
# (kept: a killed or stopped sweep resumes where it was); `report --folder` prints the tables.
set -euo pipefail
cd "$(dirname "$0")/../../.."
runs=docs/lab/2026-12-07/zone_patrol_v1
python benchmarks/zone_patrol_value.py run --folder "$runs"
python benchmarks/zone_patrol_value.py run --folder "$runs" --seeds 0 1 2 3 4 \
    --variants em_ppo_nofusion em_ppo_team exact_belief mappo ppo_lstm
python benchmarks/zone_patrol_value.py run --folder "${runs}_confirmation" --seeds 10 11 12 13 14 15 16 17 18 19 \
    --variants told ppo em_ppo
