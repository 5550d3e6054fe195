"""Campaigns against real processes: Ctrl-C, SIGKILL of the parent, two writers in one folder.

Each case ends with the same records as an uninterrupted run (wall-clock solve times aside).
"""

import multiprocessing
import os
import signal
import sys

import pytest

from helpers_campaign import alive, assert_same_records, descendants, small, start_campaign, wait_for_records
from uuv_ocp.studies.campaign import run_campaign
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


def check_sound_records(directory, config):
    """Every record on disk verifies for its trial; no temporary file is left."""
    records = sorted(directory.glob("trial_*.npz"))
    for path in records:
        assert read_record(path, config.trial_settings(int(path.stem[-4:])), steps=config.steps()) is not None
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
    assert check_sound_records(directory, small(trials=TRIALS)) < TRIALS
    resumed = run_campaign(small(trials=TRIALS), tmp_path, workers=1, progress=False)
    assert not resumed.recomputed
    assert_same_records(directory, uninterrupted.directory, TRIALS)


def test_two_campaigns_into_one_folder_give_complete_sound_records(tmp_path, uninterrupted):
    first, second = start_campaign(tmp_path, 1, TRIALS), start_campaign(tmp_path, 1, TRIALS)
    for process in (first, second):
        _, err = process.communicate(timeout=300)
        assert process.returncode == 0, err
        assert "Warning" not in err  # neither read a half-written record of the other
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
