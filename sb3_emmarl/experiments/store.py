"""The embedded store of an experiment's cells (SQLite, Python's own ``sqlite3``): one row per finished (experiment,
budget, algorithm, condition, seed), written once the cell has trained and been evaluated, so that a runner killed
mid-way and started again only runs the cells that are missing; and the claims of the cells that are running.

Several runners can share one store (on one machine, or on machines that share its file): a runner claims a cell in
the store (a lease: the runner's id, host and process, and a heartbeat it renews) before it starts it, in a
transaction that takes SQLite's write lock first (``BEGIN IMMEDIATE``), so that two runners never start the same
cell. A claim stops holding its cell when its runner is gone: on the claim's own host when the runner's process no
longer exists (seen at once, whatever the heartbeat), on another host when the heartbeat is older than the lease. The
next runner then takes the cell over (and only then clears the folder its dead owner left behind).

Every finished cell names the package version and the git commit that made it (``"unknown"`` for cells stored before
the columns existed, and for the commit outside a git checkout).
"""

from __future__ import annotations

import errno
import json
import os
import socket
import sqlite3
import subprocess
import time
import uuid
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

#: What a cell stored without a version (before the store recorded them) is reported as.
UNKNOWN = "unknown"
#: Seconds after its last heartbeat that a claim from another host stops holding its cell (the default lease).
LEASE_SECONDS = 120.0

SCHEMA = (
    """
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
    version TEXT NOT NULL DEFAULT 'unknown',
    git_commit TEXT NOT NULL DEFAULT 'unknown',
    PRIMARY KEY (experiment, budget, algorithm, condition, seed)
)
""",
    """
CREATE TABLE IF NOT EXISTS claims (
    experiment TEXT NOT NULL,
    budget TEXT NOT NULL,
    algorithm TEXT NOT NULL,
    condition TEXT NOT NULL,
    seed INTEGER NOT NULL,
    runner TEXT NOT NULL,
    host TEXT NOT NULL,
    pid INTEGER NOT NULL,
    process_start TEXT NOT NULL,
    heartbeat REAL NOT NULL,
    PRIMARY KEY (experiment, budget, algorithm, condition, seed)
)
""",
)
#: Columns added to ``cells`` since its first schema: stores written before them get them with these defaults.
ADDED_COLUMNS = {"version": f"TEXT NOT NULL DEFAULT '{UNKNOWN}'", "git_commit": f"TEXT NOT NULL DEFAULT '{UNKNOWN}'"}

Cell = tuple[str, str, int]


#: The errno of the SQLite errors that are the file system's (a full disk, a read-only or unopenable file).
_SQLITE_ERRNO = {sqlite3.SQLITE_FULL: errno.ENOSPC, sqlite3.SQLITE_READONLY: errno.EROFS,
                 sqlite3.SQLITE_CANTOPEN: errno.EACCES, sqlite3.SQLITE_IOERR: errno.EIO, sqlite3.SQLITE_PERM: errno.EACCES}


def _os_error(error: sqlite3.OperationalError, path: Path) -> Exception:
    """``error`` as the ``OSError`` naming the store that it is when the file system refused a write (the commands
    report those in one line), else ``error`` itself."""
    code = getattr(error, "sqlite_errorcode", None)
    if code in _SQLITE_ERRNO:
        return OSError(_SQLITE_ERRNO[code], f"{os.strerror(_SQLITE_ERRNO[code])} ({error})", str(path))
    return error


def _stat(pid: int) -> list[str] | None:
    """The fields of ``/proc/<pid>/stat`` after the command's name (state first), or None where ``/proc`` has no such
    process (or there is no ``/proc``: not Linux)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def _process_start(pid: int) -> str:
    """When a process started (``/proc/<pid>/stat``'s start time, in clock ticks since boot), to tell it from a later
    process that reuses its id; ``""`` where ``/proc`` is missing (not Linux) or the process does not exist."""
    fields = _stat(pid)
    return fields[19] if fields is not None and len(fields) > 19 else ""


def process_alive(pid: int, start: str = "") -> bool:
    """Whether process ``pid`` of this machine runs (a zombie does not), and is the one that started at ``start``
    (:func:`_process_start`; ``""``: any)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # it exists, owned by another user
    fields = _stat(pid)
    if fields is None or len(fields) <= 19:
        return not os.path.isdir("/proc/self")  # gone meanwhile; or no /proc, where os.kill's answer is all there is
    return fields[0] not in ("Z", "X") and (not start or fields[19] == start)


@cache
def code_version() -> tuple[str, str]:
    """This code's package version (``sb3_emmarl.version.__version__``) and git commit: the checkout's ``HEAD`` with
    ``+dirty`` when tracked files of the packages or the zoo differ from it, or :data:`UNKNOWN` when the package is
    not in a git checkout of its own (an installed wheel) or git is missing."""
    from sb3_emmarl.version import __version__

    root = Path(__file__).resolve().parents[2]  # the checkout that holds sb3_emmarl/, if any

    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=30,
                              check=True).stdout.strip()

    try:
        if Path(git("rev-parse", "--show-toplevel")).resolve() != root:
            return __version__, UNKNOWN  # installed inside somebody else's repository
        commit = git("rev-parse", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no", "--", "sb3_emmarl", "envs", "zoo")
    except (OSError, subprocess.SubprocessError):
        return __version__, UNKNOWN
    return __version__, commit + ("+dirty" if dirty else "")


@dataclass(frozen=True)
class RunnerId:
    """Who holds a claim: a fresh id per runner, its host, its process and when that process started.

    :param id: unique per runner (a random UUID by default)
    :param host: the machine's name
    :param pid: the runner's process
    :param process_start: when that process started (tells it from a later process with the same id)
    """

    id: str = field(default_factory=lambda: uuid.uuid4().hex)
    host: str = field(default_factory=socket.gethostname)
    pid: int = field(default_factory=os.getpid)
    process_start: str = field(default_factory=lambda: _process_start(os.getpid()))


@dataclass(frozen=True)
class Claim:
    """A cell this runner now holds.

    :param cell: (algorithm, condition, seed)
    :param previous: the runner whose dead or expired claim this one replaces (its folder is stale), or None
    """

    cell: Cell
    previous: str | None = None


class ResultStore:
    """The finished and the running cells of every experiment, in one SQLite file.

    :param path: the database file (created with its folder if missing; an older store gets the version columns,
        ``"unknown"`` for its cells)
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self._transaction() as db:
            for statement in SCHEMA:
                db.execute(statement)
            columns = {row[1] for row in db.execute("PRAGMA table_info(cells)")}
            for column, declaration in ADDED_COLUMNS.items():
                if column not in columns:
                    db.execute(f"ALTER TABLE cells ADD COLUMN {column} {declaration}")

    def _connect(self) -> sqlite3.Connection:
        return sqlite3.connect(self.path, timeout=60, isolation_level=None)

    @contextmanager
    def _transaction(self) -> Iterator[sqlite3.Connection]:
        """One write transaction that holds SQLite's write lock from its start (no two runners read the same free
        cell and both claim it); committed on success, rolled back on an error."""
        db = self._connect()
        try:
            db.execute("BEGIN IMMEDIATE")
            try:
                yield db
            except BaseException:
                if db.in_transaction:  # (SQLite has rolled back itself after a full disk)
                    db.execute("ROLLBACK")
                raise
            db.execute("COMMIT")
        except sqlite3.OperationalError as error:
            raise _os_error(error, self.path) from error
        finally:
            db.close()

    def finished(self, experiment: str, budget: str, version: str | None = None) -> set[Cell]:
        """The (algorithm, condition, seed) cells of an experiment and budget that are in the store.

        :param version: only the cells stored by this package version (None: every cell)
        """
        query = "SELECT algorithm, condition, seed FROM cells WHERE experiment = ? AND budget = ?"
        params: tuple = (experiment, budget)
        if version is not None:
            query, params = query + " AND version = ?", (*params, version)
        db = self._connect()
        try:
            rows = db.execute(query, params).fetchall()
        finally:
            db.close()
        return {(a, c, int(s)) for a, c, s in rows}

    def claim(self, experiment: str, budget: str, cells: Iterable[Cell], runner: RunnerId,
              lease_seconds: float = LEASE_SECONDS, version: str | None = None) -> Claim | None:
        """Claim the first of ``cells`` that is neither finished nor held by a live claim of another runner.

        :param experiment: the experiment's name
        :param budget: its budget
        :param cells: the candidates, in the order to take them
        :param runner: who claims
        :param lease_seconds: how long after its last heartbeat a claim from another host stops holding its cell
        :param version: a finished cell counts only when stored by this version (None: any)
        :return: the claim, or None when every candidate is finished or held
        """
        with self._transaction() as db:
            done = {(a, c, int(s)) for a, c, s, v in db.execute(
                "SELECT algorithm, condition, seed, version FROM cells WHERE experiment = ? AND budget = ?",
                (experiment, budget)) if version is None or v == version}
            held = {(a, c, int(s)): (r, h, p, ps, hb) for a, c, s, r, h, p, ps, hb in db.execute(
                "SELECT algorithm, condition, seed, runner, host, pid, process_start, heartbeat FROM claims "
                "WHERE experiment = ? AND budget = ?", (experiment, budget))}
            now = time.time()
            for cell in cells:
                if cell in done:
                    continue
                previous = None
                if cell in held:
                    owner, host, pid, start, heartbeat = held[cell]
                    if owner == runner.id or _holds(host, pid, start, heartbeat, now, lease_seconds):
                        continue
                    previous = owner
                db.execute("INSERT OR REPLACE INTO claims (experiment, budget, algorithm, condition, seed, runner, host, "
                           "pid, process_start, heartbeat) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                           (experiment, budget, *cell, runner.id, runner.host, runner.pid, runner.process_start, now))
                return Claim(cell, previous)
        return None

    def held_by_others(self, experiment: str, budget: str, runner: RunnerId,
                       lease_seconds: float = LEASE_SECONDS) -> set[Cell]:
        """The cells that live claims of other runners hold (and that are not finished)."""
        db = self._connect()
        try:
            claims = db.execute("SELECT algorithm, condition, seed, runner, host, pid, process_start, heartbeat FROM "
                                "claims WHERE experiment = ? AND budget = ?", (experiment, budget)).fetchall()
        finally:
            db.close()
        now = time.time()
        return {(a, c, int(s)) for a, c, s, r, h, p, ps, hb in claims
                if r != runner.id and _holds(h, p, ps, hb, now, lease_seconds)}

    def heartbeat(self, runner: RunnerId) -> None:
        """Renew every claim of ``runner``."""
        with self._transaction() as db:
            db.execute("UPDATE claims SET heartbeat = ? WHERE runner = ?", (time.time(), runner.id))

    def release(self, runner: RunnerId, cell: Cell | None = None) -> None:
        """Drop ``runner``'s claim of ``cell`` (None: all its claims), so that another runner can take them at once."""
        with self._transaction() as db:
            if cell is None:
                db.execute("DELETE FROM claims WHERE runner = ?", (runner.id,))
            else:
                db.execute("DELETE FROM claims WHERE runner = ? AND algorithm = ? AND condition = ? AND seed = ?",
                           (runner.id, *cell))

    def record(self, experiment: str, budget: str, cell: Cell, metrics: dict[str, float],
               episodes: list[dict[str, Any]], run_dir: str, hardware: str, *, runner: RunnerId | None = None,
               version: tuple[str, str] | None = None) -> bool:
        """Store one finished cell (replacing an earlier result of the same cell) and drop its claim.

        :param experiment: the experiment's name
        :param budget: the budget
        :param cell: (algorithm, condition, seed)
        :param metrics: the cell's metrics (name -> value)
        :param episodes: its evaluation records
        :param run_dir: the folder of its run
        :param hardware: what it ran on
        :param runner: the runner that claimed the cell: the result is stored only while its claim holds (a runner
            whose lease expired and whose cell another runner took over stores nothing); None: unclaimed
        :param version: (package version, git commit) that made the cell (default: :func:`code_version`)
        :return: whether the cell was stored
        """
        version = code_version() if version is None else version
        algorithm, condition, seed = cell
        cell = (algorithm, condition, int(seed))
        with self._transaction() as db:
            if runner is not None:
                owner = db.execute("SELECT runner FROM claims WHERE experiment = ? AND budget = ? AND algorithm = ? "
                                   "AND condition = ? AND seed = ?", (experiment, budget, *cell)).fetchone()
                if owner is None or owner[0] != runner.id:
                    return False
                db.execute("DELETE FROM claims WHERE experiment = ? AND budget = ? AND algorithm = ? AND condition = ? "
                           "AND seed = ?", (experiment, budget, *cell))
            db.execute("INSERT OR REPLACE INTO cells (experiment, budget, algorithm, condition, seed, metrics, episodes, "
                       "run_dir, hardware, version, git_commit) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                       (experiment, budget, *cell, json.dumps(metrics, sort_keys=True),
                        json.dumps(episodes, sort_keys=True), run_dir, hardware, *version))
        return True

    def rows(self, experiment: str, budget: str) -> list[dict[str, Any]]:
        """The finished cells as dicts: ``algorithm``, ``condition``, ``seed``, ``metrics`` (name -> value),
        ``episodes`` (the evaluation records), ``run_dir``, ``hardware``, ``finished_at``, ``version`` and
        ``git_commit``; ordered by algorithm, condition and seed."""
        db = self._connect()
        try:
            rows = db.execute("SELECT algorithm, condition, seed, metrics, episodes, run_dir, hardware, finished_at, "
                              "version, git_commit FROM cells WHERE experiment = ? AND budget = ? "
                              "ORDER BY algorithm, condition, seed", (experiment, budget)).fetchall()
        finally:
            db.close()
        return [{"algorithm": a, "condition": c, "seed": int(s), "metrics": json.loads(m), "episodes": json.loads(e),
                 "run_dir": r, "hardware": h, "finished_at": f, "version": v, "git_commit": g}
                for a, c, s, m, e, r, h, f, v, g in rows]


def _holds(host: str, pid: int, process_start: str, heartbeat: float, now: float, lease_seconds: float) -> bool:
    """Whether a claim still holds its cell: on this host while its runner's process lives (however old its heartbeat:
    a stopped process's folder is not deleted under it), on another while its heartbeat is younger than the lease."""
    if host == socket.gethostname():
        return process_alive(pid, process_start)
    return now - heartbeat < lease_seconds
