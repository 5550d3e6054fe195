"""Campaigns against real processes: Ctrl-C, SIGKILL of the parent, two writers in one folder.

Each case ends with the same records as an uninterrupted run (wall-clock solve times aside).
"""

import multiprocessing
import os
import signal
import sys

import pytest

from tests.helpers_campaign import (
    CLI_FLAGS,
    KILL_ENV,
    alive,
    assert_same_records,
    descendants,
    killing_trial_task,
    small,
    start_campaign,
    wait_for_records,
)
from uuv_ocp import cli
from uuv_ocp.studies import campaign as campaign_module
from uuv_ocp.studies.campaign import WorkerCrashed, WorkerRestartWarning, run_campaign
from uuv_ocp.studies.executors import MAX_TRIES
from uuv_ocp.studies.records import query_trials, read_record, write_record

TRIALS = 6
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc"),
]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """Return the 6-trial campaign run once, in this process, start to end."""
    return run_campaign(small(trials=TRIALS), tmp_path_factory.mktemp("reference"), workers=1, progress=False)


def check_sound_records(directory, config, killed=False):
    """Every record on disk verifies for its trial; no temporary file is left.

    ``killed``: a writer SIGKILLed mid-write may have left its temporary file (no record);
    the resume sweeps it (``records.sweep_temporaries``).
    """
    records = sorted(directory.glob("trial_*.npz"))
    for path in records:
        assert read_record(path, config.trial_settings(int(path.stem[-4:])), steps=config.steps()) is not None
    if not killed:
        assert not list(directory.glob(".*.tmp"))
    return len(records)


@pytest.mark.parametrize("workers", [1, 2])
def test_ctrl_c_stops_the_campaign_writes_no_unfinished_trial_and_resume_matches(
    tmp_path, uninterrupted, workers
):
    process = start_campaign(tmp_path, workers, TRIALS)
    directory = tmp_path / small().name
    wait_for_records(directory, 1, process)
    os.killpg(process.pid, signal.SIGINT)  # Ctrl-C reaches the whole foreground group
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "interrupted" in err
    assert check_sound_records(directory, small(trials=TRIALS)) < TRIALS
    resumed = run_campaign(small(trials=TRIALS), tmp_path, workers=1, progress=False)
    assert resumed.resumed >= 1 and not resumed.recomputed
    assert_same_records(directory, uninterrupted.directory, TRIALS)


def test_sigkill_of_the_parent_takes_its_workers_and_resume_matches(tmp_path, uninterrupted):
    process = start_campaign(tmp_path, 2, TRIALS)
    directory = tmp_path / small().name
    wait_for_records(directory, 1, process)
    children = descendants(process.pid)
    assert len(children) >= 2  # the two workers (and the spawn context's resource tracker)
    process.kill()
    process.wait(timeout=30)  # not communicate(): orphans would hold its pipes open
    assert alive(children, within=5.0) == {}
    assert check_sound_records(directory, small(trials=TRIALS), killed=True) < TRIALS
    resumed = run_campaign(small(trials=TRIALS), tmp_path, workers=1, progress=False)
    assert not resumed.recomputed
    assert check_sound_records(directory, small(trials=TRIALS)) == TRIALS  # swept on resume
    assert_same_records(directory, uninterrupted.directory, TRIALS)


def test_two_campaigns_into_one_folder_give_complete_sound_records(tmp_path, uninterrupted):
    first, second = start_campaign(tmp_path, 1, TRIALS), start_campaign(tmp_path, 1, TRIALS)
    for process in (first, second):
        _, err = process.communicate(timeout=300)
        assert process.returncode == 0, err
        # neither read a half-written record of the other (the CLI shows warnings as "warning: ...")
        assert not [line for line in err.splitlines() if line.startswith("warning: ") or "Warning: " in line]
    directory = tmp_path / small().name
    assert check_sound_records(directory, small(trials=TRIALS)) == TRIALS
    assert_same_records(directory, uninterrupted.directory, TRIALS)
    assert [row["trial"] for row in query_trials(tmp_path)] == list(range(TRIALS))


def _hammer(path, source, barrier, writes):
    from uuv_ocp import ClosedLoopResult

    run = ClosedLoopResult.load(source)
    barrier.wait()
    for _ in range(writes):
        write_record(path, run, {"trial": 0})


def test_synchronised_writers_of_one_record_never_clash(tmp_path, uninterrupted):
    # the race: 400 synchronised writes of one trial gave 201 FileNotFoundErrors
    source = str(uninterrupted.directory / "trial_0000.npz")
    path = tmp_path / "trial_0000.npz"
    context = multiprocessing.get_context("spawn")
    barrier = context.Barrier(2)
    writers = [context.Process(target=_hammer, args=(path, source, barrier, 200)) for _ in range(2)]
    for writer in writers:
        writer.start()
    for writer in writers:
        writer.join(120)
    assert [writer.exitcode for writer in writers] == [0, 0]
    assert read_record(path, {"trial": 0}) is not None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["trial_0000.npz"]


def _kill_in_worker(monkeypatch, tmp_path, trial, mode):
    """Run the campaign's trials through killing_trial_task; return its marker file (one line a kill)."""
    marker = tmp_path / f"killed_{trial}.txt"
    monkeypatch.setenv(KILL_ENV, f"{trial}:{mode}:{marker}")  # spawned workers inherit it
    monkeypatch.setattr(campaign_module, "trial_task", killing_trial_task)  # pickled by reference
    return marker


def test_a_local_worker_killed_mid_campaign_is_replaced_and_its_trial_rerun(
    tmp_path, uninterrupted, monkeypatch
):
    marker = _kill_in_worker(monkeypatch, tmp_path, 1, "once")
    out = tmp_path / "out"
    with pytest.warns(WorkerRestartWarning, match=r"worker process died.*trial 1") as caught:
        result = run_campaign(small(trials=TRIALS), out, workers=2, progress=False)
    assert len(marker.read_text().split()) == 1  # it did die, once
    restarts = [w for w in caught if issubclass(w.category, WorkerRestartWarning)]
    assert len(restarts) == 1 and "\n" not in str(restarts[0].message)
    assert result.resumed == 0 and len(result.trials) == TRIALS
    assert check_sound_records(result.directory, small(trials=TRIALS)) == TRIALS
    assert_same_records(result.directory, uninterrupted.directory, TRIALS)
    assert [row["trial"] for row in query_trials(out)] == list(range(TRIALS))


def test_a_trial_that_kills_its_worker_every_time_is_given_up_after_max_tries(
    tmp_path, uninterrupted, monkeypatch, capsys
):
    marker = _kill_in_worker(monkeypatch, tmp_path, 2, "always")
    out = tmp_path / "out"
    with (
        pytest.warns(WorkerRestartWarning),
        pytest.raises(WorkerCrashed, match=rf"trial 2: the worker process died each of the {MAX_TRIES}"),
    ):
        run_campaign(small(trials=TRIALS), out, workers=2, progress=False)
    assert len(marker.read_text().split()) == MAX_TRIES  # bounded: no endless loop
    directory = out / small().name
    others = [i for i in range(TRIALS) if i != 2]
    assert sorted(int(p.stem[-4:]) for p in directory.glob("trial_*.npz")) == others
    assert_same_records(directory, uninterrupted.directory, others)
    # the command line: one line, exit status 2
    marker.unlink()
    code = cli.main(
        ["campaign", *CLI_FLAGS, "--trials", "3", "--workers", "2", "--out", str(tmp_path / "cli")]
    )
    err = capsys.readouterr().err
    assert code == 2 and err.count("error:") == 1 and "trial 2" in err
    assert [line for line in err.splitlines() if line.startswith("warning:")]  # the restarts, one line each
