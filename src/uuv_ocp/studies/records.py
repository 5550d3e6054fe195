"""Checked records of closed-loop runs and the SQLite index of finished campaign trials.

A *record* is one :class:`~uuv_ocp.control.simulation.ClosedLoopResult` in a compressed
``.npz`` file together with the configuration that produced it (canonical JSON, array
``record_config``) and a SHA-256 checksum over every array and that configuration (array
``record_checksum``).  :func:`write_record` writes it under a unique temporary name in the same
folder (:func:`tempfile.mkstemp`) and renames it into place (:func:`os.replace`, atomic), so two
writers of the same record never see each other's half-written file and a killed writer leaves
no record.  :func:`read_record` trusts nothing: a file that does not load (truncated, empty), has
no checksum, fails it (altered: NaN-filled, shortened), was written for another configuration
(copied from another trial or campaign), or is inconsistent in itself is reported by path with a
:class:`RecordWarning` and treated as missing, so the caller recomputes it.

The index (:data:`INDEX_NAME` in a campaign's output folder) lists every finished trial of
every campaign written there, in SQLite (standard library) in WAL mode with a busy timeout, so
that two campaigns writing into one folder never corrupt it and readers never block writers.
Schema (:data:`SCHEMA`), one row per record file::

    trials(
        path      TEXT PRIMARY KEY,  -- record file relative to the index's folder
        campaign  TEXT NOT NULL,     -- campaign folder name (CampaignConfig.name)
        trial     INTEGER NOT NULL,  -- trial index
        key       TEXT NOT NULL,     -- SHA-256 of the trial's configuration (config_key)
        checksum  TEXT NOT NULL,     -- the record's checksum
        vehicle   TEXT NOT NULL,     -- vehicle spec
        reference TEXT NOT NULL,     -- reference spec
        solver    TEXT NOT NULL,
        seed      INTEGER NOT NULL,  -- campaign seed
        steps     INTEGER NOT NULL,  -- control steps recorded
        fault     TEXT,              -- why the run stopped early, NULL if it did not
        max_abs_ex REAL, max_abs_ey REAL, var_ex REAL, var_ey REAL,  -- m, m, m², m²
        metrics   TEXT NOT NULL,     -- JSON of ClosedLoopResult.metrics()
        config    TEXT NOT NULL,     -- JSON of the trial's configuration
        written   REAL NOT NULL      -- Unix time of the write (s)
    )

:func:`query_trials` reads it back; any SQLite client can too, e.g.
``sqlite3 out/campaigns/index.sqlite "SELECT solver, avg(max_abs_ex) FROM trials GROUP BY solver"``.
The record files stay the authority: the index is rebuilt from them on every resume.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import sqlite3
import tempfile
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from uuv_ocp.control.simulation import ClosedLoopResult

INDEX_NAME = "index.sqlite"
BUSY_TIMEOUT = 60.0  # s a writer waits for another writer's transaction before giving up
SCHEMA = """
CREATE TABLE IF NOT EXISTS trials (
    path TEXT PRIMARY KEY,
    campaign TEXT NOT NULL,
    trial INTEGER NOT NULL,
    key TEXT NOT NULL,
    checksum TEXT NOT NULL,
    vehicle TEXT NOT NULL,
    reference TEXT NOT NULL,
    solver TEXT NOT NULL,
    seed INTEGER NOT NULL,
    steps INTEGER NOT NULL,
    fault TEXT,
    max_abs_ex REAL,
    max_abs_ey REAL,
    var_ex REAL,
    var_ey REAL,
    metrics TEXT NOT NULL,
    config TEXT NOT NULL,
    written REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS trials_by_campaign ON trials (campaign, trial);
"""
_META = ("record_config", "record_checksum")


class RecordWarning(UserWarning):
    """A saved record could not be trusted (the message names the file and why); it is recomputed."""


def _plain(value: Any) -> Any:
    """JSON-ready form of configuration values (dataclasses, numpy arrays and scalars, paths)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {item.name: _plain(getattr(value, item.name)) for item in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, Mapping):
        return {str(key): _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)  # JSON has no NaN/inf; their repr is unambiguous
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    if isinstance(value, Path):
        return str(value)
    raise ValueError(f"configuration values must be plain data, got {type(value).__name__}: {value!r}")


def canonical(config: Mapping[str, Any]) -> str:
    """Canonical JSON of a configuration (sorted keys, no spaces): what keys and checksums cover."""
    return json.dumps(_plain(config), sort_keys=True, separators=(",", ":"), allow_nan=False)


def config_key(config: Mapping[str, Any]) -> str:
    """SHA-256 (hex) of :func:`canonical` ``config``: the identity of a run."""
    return hashlib.sha256(canonical(config).encode()).hexdigest()


def checksum(arrays: Mapping[str, np.ndarray], config_json: str) -> str:
    """SHA-256 (hex) over every array (name, dtype, shape, bytes, in name order) and the configuration."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        array = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}|{array.dtype.str}|{array.shape}|".encode())
        digest.update(array.tobytes())
    digest.update(config_json.encode())
    return digest.hexdigest()


def check_writable(folder: str | Path, name: str = "out_dir") -> Path:
    """Create ``folder`` and prove it writable by creating a file there; ``ValueError`` otherwise."""
    path = Path(folder)
    try:
        path.mkdir(parents=True, exist_ok=True)
        handle, probe = tempfile.mkstemp(dir=path, prefix=".write-test-")
        os.close(handle)
        os.unlink(probe)
    except OSError as error:
        raise ValueError(f"{name} {folder}: not a writable folder ({error.strerror or error})") from None
    return path


def write_record(path: str | Path, run: ClosedLoopResult, config: Mapping[str, Any]) -> str:
    """Write ``run`` with ``config`` and their checksum to ``path`` atomically; return the checksum."""
    path = Path(path)
    arrays: dict[str, Any] = run.arrays()
    config_json = canonical(config)
    digest = checksum(arrays, config_json)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as stream:
            np.savez_compressed(
                stream, **arrays, record_config=np.array(config_json), record_checksum=np.array(digest)
            )
            stream.flush()
            os.fsync(stream.fileno())
        os.chmod(temporary, 0o644)  # mkstemp's 0600 would hide results from the other users of a share
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return digest


def _difference(saved: str, expected: str) -> str:
    """Return the top-level keys in which two canonical configurations differ."""
    try:
        left, right = json.loads(saved), json.loads(expected)
    except ValueError:
        return "unreadable configuration"
    keys = sorted(k for k in set(left) | set(right) if left.get(k) != right.get(k))
    return ", ".join(f"{k}: {left.get(k, '—')!r} instead of {right.get(k, '—')!r}" for k in keys[:4])


def _problem(path: Path, config_json: str, steps: int | None) -> tuple[ClosedLoopResult | None, str, str]:
    """``(run, checksum, "")`` for a sound record, ``(None, "", reason)`` otherwise."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except Exception as error:  # zipfile, EOF, pickle-refusal errors: all mean "not a record"
        return None, "", f"unreadable ({type(error).__name__}: {error}); truncated or not a record"
    if any(name not in arrays for name in _META):
        return None, "", "no checksum (not written by uuv_ocp's record writer)"
    saved_json, saved_digest = str(arrays.pop("record_config")), str(arrays.pop("record_checksum"))
    if checksum(arrays, saved_json) != saved_digest:
        return None, "", "checksum mismatch: the arrays were altered (e.g. NaN-filled or shortened)"
    if saved_json != config_json:
        return None, "", f"written for another configuration ({_difference(saved_json, config_json)})"
    try:
        run = ClosedLoopResult.from_arrays(arrays)
    except Exception as error:
        return None, "", f"not a closed-loop run ({type(error).__name__}: {error})"
    n = run.controls.shape[0]
    if run.states.shape[0] != n + 1 or run.t.shape[0] != n + 1 or len(run.statuses) != n:
        return (
            None,
            "",
            f"inconsistent lengths (t {run.t.shape[0]}, states {run.states.shape[0]}, controls {n})",
        )
    if not (np.all(np.isfinite(run.states)) and np.all(np.isfinite(run.controls))):
        return None, "", "non-finite states or controls"
    if run.interrupted:
        return None, "", "an interrupted run"
    if steps is not None and run.fault is None and n != steps:
        return None, "", f"{n} steps instead of {steps}"
    return run, saved_digest, ""


def read_record(
    path: str | Path, config: Mapping[str, Any], *, steps: int | None = None
) -> tuple[ClosedLoopResult, str] | None:
    """Return the run saved at ``path`` for ``config`` and its checksum, or ``None`` (missing or bad).

    Parameters
    ----------
    path : str or Path
        Record file.
    config : mapping
        The configuration the record must have been written for.
    steps : int, optional
        Control steps a run that did not fault must have.

    Returns
    -------
    (ClosedLoopResult, str) or None
        ``None`` when there is no file, or after a :class:`RecordWarning` naming the file and
        what is wrong with it.
    """
    path = Path(path)
    if not path.exists():
        return None
    run, digest, reason = _problem(path, canonical(config), steps)
    if run is None:
        warnings.warn(f"{path}: {reason}; recomputing it", RecordWarning, stacklevel=2)
        return None
    return run, digest


def _connect(folder: Path) -> sqlite3.Connection:
    connection = sqlite3.connect(folder / INDEX_NAME, timeout=BUSY_TIMEOUT)
    connection.execute(f"PRAGMA busy_timeout = {int(BUSY_TIMEOUT * 1000)}")
    connection.execute("PRAGMA journal_mode = WAL")  # readers never block the writer, nor it them
    connection.executescript(SCHEMA)
    return connection


def index_trial(
    folder: str | Path,
    path: str | Path,
    *,
    campaign: str,
    trial: int,
    config: Mapping[str, Any],
    digest: str,
    run: ClosedLoopResult,
    metrics: Mapping[str, float],
) -> None:
    """Insert or replace the index row of one trial record (see the module doc for the schema)."""
    folder = Path(folder)
    row = (
        str(Path(path).resolve().relative_to(folder.resolve())),
        campaign,
        int(trial),
        config_key(config),
        digest,
        str(config.get("vehicle", "")),
        str(config.get("reference", "")),
        str(config.get("solver", run.solver)),
        int(config.get("seed", 0)),
        int(run.controls.shape[0]),
        run.fault,
        float(metrics["max_abs_ex"]),
        float(metrics["max_abs_ey"]),
        float(metrics["var_ex"]),
        float(metrics["var_ey"]),
        canonical(metrics),
        canonical(config),
        time.time(),
    )
    connection = _connect(folder)
    try:
        with connection:  # one short transaction per row: concurrent writers wait, never clash
            connection.execute(f"INSERT OR REPLACE INTO trials VALUES ({', '.join('?' * len(row))})", row)
    finally:
        connection.close()


def query_trials(
    folder: str | Path,
    *,
    campaign: str | None = None,
    solver: str | None = None,
    reference: str | None = None,
    faulted: bool | None = None,
) -> list[dict[str, Any]]:
    """Rows of the index in ``folder`` (a campaign's ``out_dir``), filtered, by campaign and trial.

    Parameters
    ----------
    folder : str or Path
        The folder holding :data:`INDEX_NAME`.
    campaign, solver, reference : str, optional
        Keep only rows with this campaign name, solver or reference spec.
    faulted : bool, optional
        Keep only faulted (``True``) or only complete (``False``) trials.

    Returns
    -------
    list of dict
        One dict per row with the schema's columns; ``metrics`` and ``config`` decoded from JSON.
        Empty when the folder has no index.
    """
    folder = Path(folder)
    if not (folder / INDEX_NAME).exists():
        return []
    clauses, values = [], []
    for column, value in (("campaign", campaign), ("solver", solver), ("reference", reference)):
        if value is not None:
            clauses.append(f"{column} = ?")
            values.append(value)
    if faulted is not None:
        clauses.append("fault IS NOT NULL" if faulted else "fault IS NULL")
    where = f" WHERE {' AND '.join(clauses)}" if clauses else ""
    connection = _connect(folder)
    connection.row_factory = sqlite3.Row
    try:
        rows = connection.execute(f"SELECT * FROM trials{where} ORDER BY campaign, trial", values).fetchall()
    finally:
        connection.close()
    decoded = []
    for row in rows:
        item = dict(row)
        item["metrics"] = json.loads(item["metrics"])
        item["config"] = json.loads(item["config"])
        decoded.append(item)
    return decoded
