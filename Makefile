SHELL = /bin/bash
PYTHON ?= python
# A CPU build of torch, installed before anything can pull the multi-GB CUDA build.
TORCH_VERSION ?= 2.13.0
PIP = $(PYTHON) -m pip install --quiet --disable-pip-version-check

.PHONY: install main test pytest lint type format check-codestyle commit-checks docs docs-check benchmark-env benchmark-ppo benchmark-em benchmark-latent-tasks benchmark-em-speed \
	benchmark-mode-evidence benchmark-mixture-ceiling benchmark-zone-patrol-gate benchmark-zone-patrol-reach benchmark-zone-patrol-value benchmark-mode-value benchmark-mode-value-0-1-0 benchmark-kill-resume benchmark-fuzz benchmark-matrix-game benchmark-baselines benchmark-message-policies benchmark-train-speed \
	experiments-quick experiments-full experiments-report wheel-check

# Every extra (zoo, render, plots, ray, docs, tests, bench: setup.cfg), as the suite and the docs need them all.
install:
	$(PIP) "torch==$(TORCH_VERSION)"
	$(PIP) -e ".[all]"

# The main job: a short EM-PPO run on the default reserve (a few minutes on 2 cores), tensorboard
# logs in runs/, the run in logs/em_ppo/, then the team metrics (and latent accuracy) of 5 evaluation episodes.
main: install
	$(PYTHON) zoo/train.py --algo em_ppo --env WildlifeReserve-v1 -n 500000 --seed 0 -tb runs -f logs \
		--eval-freq -1 --team-eval-episodes 5 --verbose 0 -P

pytest:
	$(PYTHON) -m pytest -n 2 tests

test: install lint type pytest docs-check

lint:
	$(PYTHON) -m ruff check .

format:
	$(PYTHON) -m ruff check . --fix

# Import order only (ruff's isort rules), as SB3's check-codestyle does; `lint` runs every rule.
check-codestyle:
	$(PYTHON) -m ruff check --select I .

# Static types of both packages (settings in pyproject.toml's [tool.mypy]).
type:
	$(PYTHON) -m mypy sb3_emmarl envs/wildlife_reserve

commit-checks: lint type pytest

# The documentation site (Sphinx with myst-parser, as SB3's; the API reference generated from the docstrings at build
# time) in docs/_build/html; open docs/_build/html/index.html.
SPHINXBUILD = OMP_NUM_THREADS=1 $(PYTHON) -m sphinx -b html -q
docs:
	$(SPHINXBUILD) docs docs/_build/html

# The same from scratch (-E: every page re-read) with warnings as errors, as `make test` (so CI) runs it: a broken
# reference or a docstring that does not parse fails, and --keep-going lists every one before failing.
docs-check:
	$(SPHINXBUILD) -E -W --keep-going docs docs/_build/html

benchmark-env: install
	$(PYTHON) benchmarks/env_speed.py

# Decentralized PPO against the random team on the same episodes (about 10-15 minutes).
benchmark-ppo: install
	$(PYTHON) zoo/benchmark.py --algos ppo -n 3000000 --seeds 0 --eval-episodes 20

# EM-PPO, PPO, RecurrentPPO (memory without EM), PPO told the mode (the upper bound) and EM-PPO's no-latent and
# frozen-E-step ablations, 3 seeds at the same budget, paired against PPO (about 50 minutes, estimated).
benchmark-em: install
	$(PYTHON) zoo/compare.py -n 500000 --seeds 0 1 2

# Wall time of EM-PPO against PPO and RecurrentPPO at equal agent-steps, taking turns in one process (about 15 minutes).
benchmark-em-speed: install
	$(PYTHON) benchmarks/em_speed.py

# The paper's experiments (sb3_emmarl/experiments/specs): the missing cells only (a killed run resumes), then their
# tables and figures under logs/experiments/. quick: each experiment within about 30 minutes here; full: the paper's
# budget. experiments-report rewrites docs/results.md's sections and docs/figures from the quick store (--update-docs).
experiments-quick: install
	$(PYTHON) zoo/experiment.py --all --budget quick

experiments-full: install
	$(PYTHON) zoo/experiment.py --all --budget full

experiments-report: install
	$(PYTHON) zoo/experiment.py --all --budget quick --report-only --update-docs

# PPO and EM-PPO through the batched and SuperSuit paths against a zero-cost environment, raw stepping from 1 to 64
# copies and at 50 and 200 UAVs, and PPO through the zoo at 10, 50 and 200 UAVs (about 15 minutes).
benchmark-train-speed: install
	$(PYTHON) benchmarks/train_speed.py

# EM-PPO with default arguments on the four hidden-mode tasks, against PPO told the mode and plain PPO, 10 seeds with
# learning curves and EM-PPO's belief permuted (about 80 minutes; a killed run resumes), then the report.
LATENT_TASKS_FOLDER ?= logs/latent_tasks
benchmark-latent-tasks: install
	$(PYTHON) benchmarks/latent_tasks.py run --folder $(LATENT_TASKS_FOLDER)
	$(PYTHON) benchmarks/latent_tasks.py report --folder $(LATENT_TASKS_FOLDER)

# Does the hidden mode show in what a team observes? A supervised probe by patrol, source and time (about 10 minutes).
benchmark-mode-evidence: install
	$(PYTHON) benchmarks/mode_evidence.py

# How well EM-PPO's latent model tells the mode, fitted by EM and fitted told the mode (its ceiling) (about 8 minutes).
benchmark-mixture-ceiling: install
	$(PYTHON) docs/lab/studies/mixture_ceiling.py

# How much knowing the hidden mode pays: PPO told the mode against plain PPO and against a control told a random label,
# 5 seeds x 500k agent-steps each (about 35 minutes).
benchmark-mode-value: install
	$(PYTHON) benchmarks/mode_value.py

# The figure the value-of-information target was set on, repeated on its own reserve: sb3-emmarl 0.1.0 (8044dff, checked
# out as a git worktree), PPO told the mode, plain PPO and a random-label control, 10 seeds x 500k each (about 40 minutes).
MV010_TREE ?= /tmp/sb3_emmarl_0_1_0
MV010_FOLDER ?= logs/mode_value_0_1_0
benchmark-mode-value-0-1-0: install
	test -d $(MV010_TREE) || git worktree add --detach $(MV010_TREE) 8044dff
	for seed in 0 1 2 3 4 5 6 7 8 9; do for variant in told ppo control; do \
		echo "run --variant $$variant --seed $$seed --folder $(MV010_FOLDER)"; done; done | \
		PYTHONPATH=$(MV010_TREE):$(MV010_TREE)/envs xargs -P 2 -L 1 $(PYTHON) docs/lab/studies/mode_value_0_1_0.py
	$(PYTHON) docs/lab/studies/mode_value_0_1_0.py report --folder $(MV010_FOLDER)

# Runs that survive: 20 SIGKILLs at random moments per algorithm (PPO, EM-PPO), resumed and compared with uninterrupted runs (about 25 minutes).
benchmark-kill-resume: install
	$(PYTHON) benchmarks/kill_resume.py --kills 20 -n 32768 --save-freq 2048

# Fuzz the reserve's arguments (1000 sets) and the zoo's hyperparameters and flags (617 cases, and 377 hostile ones); prints the counts (about 2 minutes).
benchmark-fuzz: install
	$(PYTHON) benchmarks/fuzz_reserve.py --cases 1000 --seed 0
	$(PYTHON) benchmarks/fuzz_zoo.py

# QMIX and VDN on QMIX's two-step matrix game, 5 seeds each (QMIX should reach 8, VDN 7; about 3 minutes).
benchmark-matrix-game: install
	$(PYTHON) benchmarks/matrix_game.py

# MAPPO, QMIX, VDN and VDN+EM against PPO and EM-PPO on the default reserve, 3 seeds x 300k agent-steps (about 30 minutes on 0.17.0).
benchmark-baselines: install
	$(PYTHON) zoo/compare.py --variants ppo em_ppo mappo qmix vdn vdn_em --seeds 0 1 2 -n 300000 --n-jobs 2

# The paper's table 6: PPO with graph attention and with a transformer over the messages, against PPO and EM-PPO, 3 seeds x 200k agent-steps (about 25 minutes).
benchmark-message-policies: install
	$(PYTHON) zoo/compare.py --variants ppo em_ppo ppo_gat ppo_transformer --seeds 0 1 2 -n 200000 --n-jobs 2

# ZonePatrol's gate, no training: the told scripted team against the best blind one on 300 held-out episodes, and the
# stepping speed against the reserve (about a minute).
benchmark-zone-patrol-gate: install
	$(PYTHON) benchmarks/zone_patrol_gate.py

# Where a ZonePatrol team's evidence goes, no training: the evidence reach along the links and the exact posterior's
# accuracy from one UAV's, the linked and the whole team's readings, for scripted teams at several ranges (a minute).
benchmark-zone-patrol-reach: install
	$(PYTHON) benchmarks/zone_patrol_reach.py

# What knowing the mode pays a learned team on ZonePatrol: told PPO, PPO, the random-label control and EM-PPO, 10 seeds
# x 1M agent-steps, then the arms beside them on seeds 0-4 and the confirmation on seeds 10-19 (about 7 hours on 2 cores;
# a killed run resumes), then the two reports (docs/zone_patrol.md's protocol).
ZONE_PATROL_FOLDER ?= logs/zone_patrol_value
benchmark-zone-patrol-value: install
	$(PYTHON) benchmarks/zone_patrol_value.py run --folder $(ZONE_PATROL_FOLDER)
	$(PYTHON) benchmarks/zone_patrol_value.py run --folder $(ZONE_PATROL_FOLDER) --seeds 0 1 2 3 4 \
		--variants em_ppo_nofusion em_ppo_team exact_belief ppo_lstm mappo
	$(PYTHON) benchmarks/zone_patrol_value.py run --folder $(ZONE_PATROL_FOLDER)_confirmation \
		--seeds 10 11 12 13 14 15 16 17 18 19 --variants told ppo em_ppo
	$(PYTHON) benchmarks/zone_patrol_value.py report --folder $(ZONE_PATROL_FOLDER)
	$(PYTHON) benchmarks/zone_patrol_value.py report --folder $(ZONE_PATROL_FOLDER)_confirmation

# The package as a user gets it: the wheel in a fresh venv outside the checkout, core only (trains EM-PPO; no rl_zoo3,
# pygame or matplotlib; the zoo's import says which extra to add), then with [zoo]: emmarl train, enjoy, experiment
# --list (about 15 minutes, most of it installing torch and compiling the reserve's kernels once).
wheel-check:
	$(PYTHON) benchmarks/wheel_check.py
