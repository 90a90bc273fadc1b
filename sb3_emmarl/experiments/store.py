"""The embedded store of finished cells (SQLite, Python's own ``sqlite3``): one row per (experiment, budget,
algorithm, condition, seed), written once the cell has trained and been evaluated, so that a runner killed mid-way
and started again only runs the cells that are missing.

Only the runner's own process writes (cells run elsewhere return their results to it), one transaction per cell.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any

SCHEMA = """
CREATE TABLE IF NOT EXISTS cells (
    experiment TEXT NOT NULL,
    budget TEXT NOT NULL,
    algorithm TEXT NOT NULL,
    condition TEXT NOT NULL,
    seed INTEGER NOT NULL,
    metrics TEXT NOT NULL,
    episodes TEXT NOT NULL,
    run_dir TEXT NOT NULL,
    hardware TEXT NOT NULL,
    finished_at TEXT NOT NULL DEFAULT (datetime('now')),
    PRIMARY KEY (experiment, budget, algorithm, condition, seed)
)
"""


class ResultStore:
    """The finished cells of every experiment, in one SQLite file.

    :param path: the database file (created with its folder if missing)
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self._connect() as db:
            db.execute(SCHEMA)

    def _connect(self) -> sqlite3.Connection:
        return sqlite3.connect(self.path, timeout=60)

    def finished(self, experiment: str, budget: str) -> set[tuple[str, str, int]]:
        """The (algorithm, condition, seed) cells of an experiment and budget that are in the store."""
        with self._connect() as db:
            rows = db.execute("SELECT algorithm, condition, seed FROM cells WHERE experiment = ? AND budget = ?",
                              (experiment, budget)).fetchall()
        return {(a, c, int(s)) for a, c, s in rows}

    def record(self, experiment: str, budget: str, algorithm: str, condition: str, seed: int,
               metrics: dict[str, float], episodes: list[dict[str, Any]], run_dir: str, hardware: str) -> None:
        """Store one finished cell (replacing an earlier result of the same cell)."""
        with self._connect() as db:
            db.execute("INSERT OR REPLACE INTO cells (experiment, budget, algorithm, condition, seed, metrics, episodes, "
                       "run_dir, hardware) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                       (experiment, budget, algorithm, condition, int(seed), json.dumps(metrics, sort_keys=True),
                        json.dumps(episodes, sort_keys=True), run_dir, hardware))

    def rows(self, experiment: str, budget: str) -> list[dict[str, Any]]:
        """The finished cells as dicts: ``algorithm``, ``condition``, ``seed``, ``metrics`` (name -> value),
        ``episodes`` (the evaluation records), ``run_dir``, ``hardware``, ``finished_at``; ordered by algorithm,
        condition and seed."""
        with self._connect() as db:
            rows = db.execute("SELECT algorithm, condition, seed, metrics, episodes, run_dir, hardware, finished_at "
                              "FROM cells WHERE experiment = ? AND budget = ? ORDER BY algorithm, condition, seed",
                              (experiment, budget)).fetchall()
        return [{"algorithm": a, "condition": c, "seed": int(s), "metrics": json.loads(m), "episodes": json.loads(e),
                 "run_dir": r, "hardware": h, "finished_at": f} for a, c, s, m, e, r, h, f in rows]
