"""Shared by the campaign tests: a small campaign and a comparison of its records."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from uuv_ocp.studies.campaign import CampaignConfig
from uuv_ocp.studies.campaign import trial_task as _trial_task

# wall-clock arrays differ between two runs of the same trial; the checksum covers them
WALL_CLOCK = {"solve_times", "record_checksum"}
SMALL = {"reference": "s2", "solver": "sqp", "trials": 3, "duration": 2.0, "horizon": 8, "seed": 3}
ROOT = Path(__file__).resolve().parents[1]
CLI_FLAGS = ["-r", "s2", "-s", "sqp", "--duration", "2", "--horizon", "8", "--seed", "3"]


def small(**changes):
    return CampaignConfig(**{**SMALL, **changes})


def record_arrays(path):
    with np.load(path, allow_pickle=False) as data:
        return {name: data[name] for name in data.files if name not in WALL_CLOCK}


def assert_same_records(directory, reference_directory, trials):
    """Trial records in ``directory`` equal the uninterrupted run's, array by array.

    ``trials``: a count (trials 0..trials-1) or the indices to compare.
    """
    for index in range(trials) if isinstance(trials, int) else trials:
        name = f"trial_{index:04d}.npz"
        got, expected = record_arrays(Path(directory) / name), record_arrays(Path(reference_directory) / name)
        assert got.keys() == expected.keys(), name
        for key in expected:
            np.testing.assert_array_equal(got[key], expected[key], err_msg=f"{name}: {key}")


def start_campaign(out, workers, trials, executor="local"):
    """Start ``uuv-ocp campaign`` on the small campaign in a new session (its own process group)."""
    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'src'}{os.pathsep}{ROOT}", "UUV_OCP_COMPILED": "0"}
    command = [sys.executable, "-m", "uuv_ocp.cli", "campaign", *CLI_FLAGS, "--trials", str(trials)]
    command += ["--executor", executor, "--workers", str(workers), "--out", str(out)]
    return subprocess.Popen(
        command,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=_terminal_sigint,
    )


def _terminal_sigint():
    """Give the child the SIGINT of a terminal's foreground job (default action, not ignored).

    A suite started as a background job of a non-interactive shell (``nohup make test &``)
    inherits SIGINT ignored, and a Python started so installs no KeyboardInterrupt handler: the
    Ctrl-C tests would then see a campaign that cannot be interrupted (measured: exit 0 in CI
    started that way) instead of the one a user runs from a terminal.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def wait_for_records(directory, count, process, timeout=120.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if len(list(directory.glob("trial_*.npz"))) >= count:
            return
        assert process.poll() is None, process.communicate()
        time.sleep(0.05)
    raise AssertionError(f"no {count} records in {directory} after {timeout} s")


def state(pid):
    """Return the process state letter from /proc (``Z`` zombie), or ``"gone"``."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return "gone"


def descendants(pid):
    children = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def alive(pids, within):
    """Return {pid: state} of the processes still running after waiting up to ``within`` seconds."""
    deadline = time.monotonic() + within
    while time.monotonic() < deadline and any(state(pid) not in ("gone", "Z") for pid in pids):
        time.sleep(0.1)
    return {pid: state(pid) for pid in pids if state(pid) not in ("gone", "Z")}


KILL_ENV = "UUV_OCP_TEST_KILL"  # "<trial>:<once|always>:<marker file>", read by killing_trial_task


def killing_trial_task(config, index):
    """``trial_task`` whose worker process SIGKILLs itself on trial ``<trial>`` (see KILL_ENV).

    ``once``: only the first time (the marker file records it); ``always``: every time.  Each
    kill first appends a line to the marker file, so the test counts the tries independently.
    """
    trial, mode, marker = os.environ[KILL_ENV].split(":", 2)
    if index == int(trial) and (mode == "always" or not Path(marker).exists()):
        with open(marker, "a") as stream:
            stream.write(f"{os.getpid()}\n")
        os.kill(os.getpid(), signal.SIGKILL)
    return _trial_task(config, index)
