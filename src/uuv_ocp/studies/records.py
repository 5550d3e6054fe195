"""Checked records of closed-loop runs and the SQLite index of finished campaign trials.

A *record* is one :class:`~uuv_ocp.control.simulation.ClosedLoopResult` in a compressed
``.npz`` file together with the configuration that produced it (canonical JSON, array
``record_config``) and a SHA-256 checksum over every array and that configuration (array
``record_checksum``).  :func:`write_record` writes it under a unique temporary name in the same
folder (:func:`tempfile.mkstemp`) and renames it into place (:func:`os.replace`, atomic), so two
writers of the same record never see each other's half-written file and a killed writer leaves
no record (its temporary file, named by its host and process, is removed by the next resume:
:func:`sweep_temporaries`).  :func:`read_record` trusts nothing: a file that does not load
(truncated, empty), has no checksum, fails it (altered: NaN-filled, shortened), was written
for another configuration (copied from another trial or campaign), or is inconsistent in
itself is reported by path with a :class:`RecordWarning` and treated as missing, so the
caller recomputes it.

A path that is not a regular file (a FIFO, a socket, a device, a directory) is never opened: it
is reported the same way, moved aside (renamed ``<name>.damaged-<UTC time>``) when it can be, and
recomputed.  A write that fails (disk full, quota, permissions, a directory in the way) raises
:class:`StorageError`, one line naming the folder; the temporary file is removed, so no
half-written record is left and no finished one is touched.

The index (:data:`INDEX_NAME` in a campaign's output folder) lists every finished trial of
every campaign written there, in SQLite (standard library) in WAL mode with a busy timeout
(:data:`BUSY_TIMEOUT`), so that two campaigns writing into one folder never corrupt it and
readers never block writers.  A writer that holds the index longer than that is not a campaign
(their transactions take milliseconds) but, say, an ``sqlite3`` shell left inside a
transaction: the error (:class:`StorageError`) names the index and the processes that have it
open.  :func:`check_index`, run by every campaign before it resumes, moves a damaged index aside
(garbage, truncated, another schema: renamed ``index.sqlite.damaged-<UTC time>``, kept) and
rebuilds it from the records of every campaign folder beside it (:func:`rebuild_index`).
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
The record files stay the authority: each campaign re-indexes its own records on every resume,
and a damaged or missing index is rebuilt from all of them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import json
import math
import os
import re
import socket
import sqlite3
import stat
import sys
import tempfile
import time
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from uuv_ocp.control.simulation import ClosedLoopResult

INDEX_NAME = "index.sqlite"
#: Seconds a writer of the index waits for another writer's transaction before giving up.  A
#: campaign's transaction (one row) takes milliseconds even on a loaded machine, so 5 s only
#: ever runs out on a lock that something else holds for good; then the user hears it at once.
BUSY_TIMEOUT = 5.0
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


class IndexWarning(UserWarning):
    """The index of an output folder was damaged: moved aside and rebuilt (the message says where)."""


class StorageError(OSError):
    """A record, the index or a text file could not be written or read (disk full, locked, ...).

    ``str()`` is one line naming the file or folder and what to do; ``errno`` is the cause's
    (``ENOSPC``, ``EDQUOT``, ``EACCES``, ...) or ``None`` for a locked index.
    """

    def __init__(self, message: str, code: int | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.errno = code

    def __str__(self) -> str:
        """Return the one-line message."""
        return self.message


def _write_failure(error: OSError, target: Path, what: str) -> StorageError:
    """Turn an ``OSError`` raised while writing ``target`` into a one-line :class:`StorageError`."""
    code = error.errno
    if code in (errno.ENOSPC, errno.EDQUOT):
        advice = "free space there or choose another output folder"
    elif isinstance(error, IsADirectoryError) or (code == errno.EISDIR):
        advice = f"a directory is in the way at {target}; remove or rename it"
    else:
        advice = "check the folder's permissions and space"
    reason = error.strerror or str(error)
    return StorageError(
        f"cannot write {what} {target.name} in {target.parent}: {reason}; {advice} "
        "(finished trials are saved; rerun to resume)",
        code,
    )


def write_text(path: str | Path, text: str, what: str = "file") -> None:
    """Write ``text`` to ``path`` atomically (unique temporary name, then rename; mode 0644).

    A failure raises :class:`StorageError` and leaves the previous file, if any, as it was.
    """
    path = Path(path)
    temporary = None
    try:
        handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with os.fdopen(handle, "w", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
    except OSError as error:
        if temporary is not None:
            Path(temporary).unlink(missing_ok=True)
        raise _write_failure(error, path, what) from error
    except BaseException:
        if temporary is not None:
            Path(temporary).unlink(missing_ok=True)
        raise


def set_aside(path: str | Path) -> Path | None:
    """Rename ``path`` to ``<name>.damaged-<UTC time>`` beside it (kept, never deleted).

    Returns the new path, or ``None`` when it could not be renamed (the caller says so).
    """
    path = Path(path)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    for attempt in range(100):
        target = path.with_name(f"{path.name}.damaged-{stamp}" + (f"-{attempt}" if attempt else ""))
        if os.path.lexists(target):
            continue
        try:
            os.rename(path, target)
        except OSError:
            return None
        return target
    return None


def _kind(mode: int) -> str:
    """Name of a non-regular file type, as a user would say it."""
    for test, name in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISLNK, "a dangling or looping symbolic link"),
    ):
        if test(mode):
            return name
    return "not a regular file"


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


#: ``.<stem>.<host>-<pid>.<random>.tmp``: a record's temporary file names its writer
_TEMPORARY = re.compile(r"\.(?P<stem>[^.]+)\.(?P<host>.+)-(?P<pid>\d+)\.\w+\.tmp\Z")


def _temporary_prefix(stem: str) -> str:
    """Prefix of a record's temporary file: its writer's host and process, for :func:`sweep_temporaries`."""
    return f".{stem}.{socket.gethostname()}-{os.getpid()}."


def sweep_temporaries(folder: str | Path) -> int:
    """Remove the temporary files of record writers on this host that no longer run; return how many.

    A writer killed between creating its temporary file and renaming it (SIGKILL, a lost node)
    cannot remove it.  Only files named by a process of this host that does not exist are
    removed: a live writer's (another campaign in the same folder) and those of other hosts
    on a shared folder are left alone.
    """
    host, removed = socket.gethostname(), 0
    for path in Path(folder).glob(".*.tmp"):
        match = _TEMPORARY.match(path.name)
        if match is None or match["host"] != host or _running(int(match["pid"])):
            continue
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
            removed += 1
    return removed


def _running(pid: int) -> bool:
    """Whether process ``pid`` exists on this host (another user's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def write_record(path: str | Path, run: ClosedLoopResult, config: Mapping[str, Any]) -> str:
    """Write ``run`` with ``config`` and their checksum to ``path`` atomically; return the checksum."""
    path = Path(path)
    arrays: dict[str, Any] = run.arrays()
    config_json = canonical(config)
    digest = checksum(arrays, config_json)
    temporary = None
    try:
        handle, temporary = tempfile.mkstemp(
            dir=path.parent, prefix=_temporary_prefix(path.stem), suffix=".tmp"
        )
        with os.fdopen(handle, "wb") as stream:
            np.savez_compressed(
                stream, **arrays, record_config=np.array(config_json), record_checksum=np.array(digest)
            )
            stream.flush()
            os.fsync(stream.fileno())
        os.chmod(temporary, 0o644)  # mkstemp's 0600 would hide results from the other users of a share
        os.replace(temporary, path)
    except OSError as error:  # disk full, quota, a directory in the way: one line, nothing half-written
        if temporary is not None:
            Path(temporary).unlink(missing_ok=True)
        raise _write_failure(error, path, "record") from error
    except BaseException:
        if temporary is not None:
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


def _open_regular(path: Path) -> Any:
    """Open ``path`` for reading only if it is a regular file; return the file or a reason (str).

    ``lstat`` first, then the opened descriptor is checked again (a FIFO swapped in between
    is caught too): opening a FIFO for reading would block until a writer comes, for ever.
    """
    try:
        mode = os.lstat(path).st_mode
        if stat.S_ISLNK(mode):
            mode = os.stat(path).st_mode  # a symbolic link to a record is followed, to anything else not
    except OSError as error:
        return f"cannot be examined ({error.strerror or error})"
    if not stat.S_ISREG(mode):
        return f"{_kind(mode)}, not a record file"
    try:
        descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as error:
        return f"cannot be opened ({error.strerror or error})"
    if not stat.S_ISREG(os.fstat(descriptor).st_mode):
        os.close(descriptor)
        return "not a regular file when opened, not a record file"
    if hasattr(os, "set_blocking"):
        os.set_blocking(descriptor, True)
    return os.fdopen(descriptor, "rb")


def _problem(
    path: Path, config_json: str | None, steps: int | None
) -> tuple[ClosedLoopResult | None, str, str]:
    """``(run, checksum, "")`` for a sound record, ``(None, "", reason)`` otherwise.

    ``config_json`` ``None`` accepts the configuration saved in the record (the checksum still
    covers it): what :func:`rebuild_index` needs.
    """
    stream = _open_regular(path)
    if isinstance(stream, str):
        return None, "", stream
    try:
        with stream, np.load(stream, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except Exception as error:  # zipfile, EOF, pickle-refusal errors: all mean "not a record"
        return None, "", f"unreadable ({type(error).__name__}: {error}); truncated or not a record"
    if any(name not in arrays for name in _META):
        return None, "", "no checksum (not written by uuv_ocp's record writer)"
    saved_json, saved_digest = str(arrays.pop("record_config")), str(arrays.pop("record_checksum"))
    if checksum(arrays, saved_json) != saved_digest:
        return None, "", "checksum mismatch: the arrays were altered (e.g. NaN-filled or shortened)"
    if config_json is not None and saved_json != config_json:
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
        what is wrong with it.  Something that is not a regular file (a FIFO, a directory, ...)
        is never opened: it is moved aside (:func:`set_aside`) when it can be, so that the
        recomputed record can take its place.
    """
    path = Path(path)
    if not os.path.lexists(path):
        return None
    run, digest, reason = _problem(path, canonical(config), steps)
    if run is None:
        if not _is_regular(path):
            moved = set_aside(path)
            reason += f"; moved aside to {moved.name}" if moved else "; it could not be moved aside"
        warnings.warn(f"{path}: {reason}; recomputing it", RecordWarning, stacklevel=2)
        return None
    return run, digest


def _is_regular(path: Path) -> bool:
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except OSError:
        return False


_SQLITE_CORRUPT, _SQLITE_NOTADB = 11, 26  # primary result codes: the file is not a sound database
_SQLITE_BUSY, _SQLITE_LOCKED, _SQLITE_FULL, _SQLITE_CANTOPEN = 5, 6, 13, 14
#: Extended codes of a read-only connection meeting what a writer killed mid-run left: a WAL to
#: recover (RECOVERY, CANTLOCK, CANTINIT) or a hot journal to roll back (ROLLBACK).  SQLite's
#: crash recovery, which any writer runs on opening, restores the last committed state.
_SQLITE_READONLY_CRASH = {264: "RECOVERY", 520: "CANTLOCK", 776: "ROLLBACK", 1288: "CANTINIT"}
_COLUMNS = (
    "path campaign trial key checksum vehicle reference solver seed steps fault max_abs_ex max_abs_ey "
    "var_ex var_ey metrics config written"
).split()


def _code(error: sqlite3.Error) -> int | None:
    code = getattr(error, "sqlite_errorcode", None)
    return None if code is None else code & 0xFF  # extended codes carry the primary one in the low byte


def _holders(path: Path) -> list[str]:
    """``pid (command)`` of the processes that have the index (or its WAL) open; Linux only, best effort."""
    if not sys.platform.startswith("linux"):
        return []
    targets = {str(path.resolve()), str(path.resolve()) + "-wal", str(path.resolve()) + "-shm"}
    found = []
    for fd_dir in Path("/proc").glob("[0-9]*/fd"):
        try:
            if any(os.readlink(link) in targets for link in fd_dir.iterdir()):
                command = (fd_dir.parent / "comm").read_text().strip()
                found.append(f"pid {fd_dir.parent.name} ({command})")
        except OSError:  # another user's process, or one that ended while we looked
            continue
    return found


def _index_failure(error: sqlite3.Error, path: Path) -> StorageError:
    """One-line :class:`StorageError` for an SQLite error on the index at ``path``."""
    code = _code(error)
    if code in (_SQLITE_BUSY, _SQLITE_LOCKED):
        holders = _holders(path)
        who = f"processes with it open: {', '.join(holders)}" if holders else "no process found holding it"
        return StorageError(
            f"index {path} is locked: another writer kept it for more than {BUSY_TIMEOUT:g} s "
            f"({who}); a campaign holds it for milliseconds, so look for an sqlite3 shell or "
            "program left inside a transaction, end it and rerun (finished trials are saved)"
        )
    if code == _SQLITE_FULL:
        return StorageError(
            f"cannot write index {path}: no space left in {path.parent}; free space there or choose "
            "another output folder (finished trials are saved; rerun to resume)",
            errno.ENOSPC,
        )
    if code in (_SQLITE_CORRUPT, _SQLITE_NOTADB):
        return StorageError(
            f"index {path} is damaged ({error}); the next campaign run in {path.parent} moves it "
            "aside and rebuilds it from the records"
        )
    return StorageError(f"index {path}: {error} (finished trials are saved; rerun to resume)")


def _raw_connect(path: Path) -> sqlite3.Connection:
    connection = sqlite3.connect(path, timeout=BUSY_TIMEOUT)
    try:
        connection.execute(f"PRAGMA busy_timeout = {int(BUSY_TIMEOUT * 1000)}")
        connection.execute("PRAGMA journal_mode = WAL")  # readers never block the writer, nor it them
    except BaseException:
        connection.close()
        raise
    return connection


@contextlib.contextmanager
def _index(folder: Path, *, create: bool = True) -> Iterator[sqlite3.Connection]:
    """Open the index of ``folder`` (schema created); SQLite errors become :class:`StorageError`."""
    path = folder / INDEX_NAME
    try:
        connection = _raw_connect(path)
        try:
            if create:
                connection.executescript(SCHEMA)
            yield connection
        finally:
            connection.close()
    except sqlite3.Error as error:
        raise _index_failure(error, path) from None


def _inspect(uri: str) -> tuple[list[str], int, str]:
    """Return the index's ``trials`` columns, its table count and SQLite's ``quick_check`` verdict."""
    connection = sqlite3.connect(uri, uri=True, timeout=BUSY_TIMEOUT)
    try:
        columns = [row[1] for row in connection.execute("PRAGMA table_info(trials)")]
        tables = connection.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
        verdict = connection.execute("PRAGMA quick_check").fetchone()[0]
    finally:
        connection.close()
    return columns, tables, verdict


def _damage(path: Path) -> str:
    """Return why the index at ``path`` cannot be used ("" if it is sound, or missing: SQLite makes one)."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return ""
    if not stat.S_ISREG(mode):  # SQLite would block on a FIFO, fail on a directory
        return _kind(mode)
    try:  # read-only: a damaged file is kept as it was found
        try:
            columns, tables, verdict = _inspect(f"{path.resolve().as_uri()}?mode=ro")
        except sqlite3.Error as error:
            if getattr(error, "sqlite_errorcode", None) not in _SQLITE_READONLY_CRASH:
                raise
            # what a writer killed mid-run left needs SQLite's crash recovery, which a read-only
            # connection cannot run; any writer runs it on opening (it is no damage)
            columns, tables, verdict = _inspect(path.resolve().as_uri())
    except sqlite3.Error as error:
        if _code(error) in (_SQLITE_CORRUPT, _SQLITE_NOTADB):
            return str(error)
        raise _index_failure(error, path) from None
    if verdict != "ok":
        return f"integrity check: {verdict}"
    if columns and columns != _COLUMNS:
        return f"another schema (columns {', '.join(columns)})"
    if not columns and tables:
        return "another schema (no table 'trials')"
    return ""


def check_index(folder: str | Path) -> str | None:
    """Make the index of ``folder`` usable before a campaign resumes; return what was done, or ``None``.

    A damaged index (not an SQLite database, truncated, failing SQLite's ``quick_check``, another
    schema, or not a regular file) is moved aside (:func:`set_aside`, kept for inspection) and
    rebuilt from the records (:func:`rebuild_index`); a missing one is rebuilt too (silently)
    when campaign folders hold records.  A locked index raises :class:`StorageError`.

    Returns
    -------
    str or None
        One line for the user when the index was rebuilt, else ``None``.
    """
    folder = Path(folder)
    path = folder / INDEX_NAME
    reason = _damage(path)
    if reason:
        moved = set_aside(path)
        if moved is None:
            raise StorageError(
                f"index {path} is damaged ({reason}) and could not be moved aside; remove it and rerun"
            )
        for suffix in ("-wal", "-shm"):  # they belong to the damaged file, not to the new one
            if os.path.lexists(f"{path}{suffix}"):
                os.replace(f"{path}{suffix}", f"{moved}{suffix}")
        count = rebuild_index(folder)
        return (
            f"index {path} was damaged ({reason}); moved aside to {moved.name} and rebuilt from "
            f"{count} record{'s' if count != 1 else ''}"
        )
    if not os.path.lexists(path) and any(folder.glob("*/trial_*.npz")):
        # no news for the user: a campaign killed between a record and its row leaves this
        rebuild_index(folder)
    return None


def rebuild_index(folder: str | Path) -> int:
    """Insert a row for every sound record ``<folder>/<campaign>/trial_*.npz``; return how many.

    A record is taken as it verifies against its own checksum (each campaign checks its records
    against its configuration again when it resumes); files that do not verify are skipped.
    """
    folder = Path(folder)
    rows = []
    for record in sorted(folder.glob("*/trial_*.npz")):
        if not _is_regular(record):
            continue
        run, digest, _ = _problem(record, None, None)
        if run is None:
            continue
        with np.load(record, allow_pickle=False) as data:
            config = json.loads(str(data["record_config"]))
        if not isinstance(config, dict) or record.name != f"trial_{config.get('trial', -1):04d}.npz":
            continue  # not a campaign trial, or copied from another trial: its campaign recomputes it
        rows.append(
            _row(folder, record, record.parent.name, int(config["trial"]), config, digest, run, run.metrics())
        )
    with _index(folder) as connection, connection:
        insert = f"INSERT OR REPLACE INTO trials VALUES ({', '.join('?' * len(_COLUMNS))})"
        connection.executemany(insert, rows)
    return len(rows)


def _row(
    folder: Path,
    path: str | Path,
    campaign: str,
    trial: int,
    config: Mapping[str, Any],
    digest: str,
    run: ClosedLoopResult,
    metrics: Mapping[str, float],
) -> tuple:
    return (
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
    """Insert or replace the index row of one trial record (see the module doc for the schema).

    Raises :class:`StorageError` (one line) when the index is locked for longer than
    :data:`BUSY_TIMEOUT`, the disk is full, or the index is damaged.
    """
    folder = Path(folder)
    row = _row(folder, path, campaign, trial, config, digest, run, metrics)
    with _index(folder) as connection, connection:  # one short transaction per row: writers wait, never clash
        connection.execute(f"INSERT OR REPLACE INTO trials VALUES ({', '.join('?' * len(row))})", row)


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

    Raises
    ------
    StorageError
        The index is damaged (see :func:`check_index`) or locked.
    """
    folder = Path(folder)
    if not os.path.lexists(folder / INDEX_NAME):
        return []
    reason = _damage(folder / INDEX_NAME)  # never block on a FIFO, nor decode another schema's rows
    if reason:
        raise StorageError(
            f"index {folder / INDEX_NAME} is damaged ({reason}); the next campaign run in {folder} "
            "moves it aside and rebuilds it from the records"
        )
    clauses, values = [], []
    for column, value in (("campaign", campaign), ("solver", solver), ("reference", reference)):
        if value is not None:
            clauses.append(f"{column} = ?")
            values.append(value)
    if faulted is not None:
        clauses.append("fault IS NOT NULL" if faulted else "fault IS NULL")
    where = f" WHERE {' AND '.join(clauses)}" if clauses else ""
    with _index(folder) as connection:
        connection.row_factory = sqlite3.Row
        rows = connection.execute(f"SELECT * FROM trials{where} ORDER BY campaign, trial", values).fetchall()
    decoded = []
    for row in rows:
        item = dict(row)
        item["metrics"] = json.loads(item["metrics"])
        item["config"] = json.loads(item["config"])
        decoded.append(item)
    return decoded
