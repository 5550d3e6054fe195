"""Campaigns on dask.distributed: the same records as local processes, and a worker killed mid-run."""

import os
import signal
import socket
import sys
import threading
import time

import pytest

from tests.helpers_campaign import (
    CLI_FLAGS,
    alive,
    assert_same_records,
    descendants,
    small,
    start_campaign,
    wait_for_records,
)
from uuv_ocp import cli
from uuv_ocp.studies import executors
from uuv_ocp.studies.campaign import SchedulerUnreachable, run_campaign

distributed = pytest.importorskip("dask.distributed", reason="the dask extra is not installed")
TRIALS = 4
pytestmark = pytest.mark.slow  # clusters and subprocesses: seconds each, still run in CI


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """Return the 4-trial campaign run once, in this process, start to end."""
    return run_campaign(small(trials=TRIALS), tmp_path_factory.mktemp("reference"), workers=1, progress=False)


def test_local_processes_and_a_dask_local_cluster_give_identical_records(tmp_path, uninterrupted):
    pool = run_campaign(small(trials=TRIALS), tmp_path / "pool", workers=2, progress=False)
    dask = run_campaign(small(trials=TRIALS), tmp_path / "dask", executor="dask", workers=2, progress=False)
    assert_same_records(pool.directory, uninterrupted.directory, TRIALS)
    assert_same_records(dask.directory, uninterrupted.directory, TRIALS)
    assert dask.trials[0]["max_abs_ex"] == uninterrupted.trials[0]["max_abs_ex"]


def test_a_dask_worker_killed_mid_campaign_loses_no_trial(tmp_path, uninterrupted):
    directory = tmp_path / small().name
    killed = []

    def kill_one_worker_after_the_first_record(pid):
        deadline = time.monotonic() + 120
        while not list(directory.glob("trial_*.npz")) and time.monotonic() < deadline:
            time.sleep(0.02)
        os.kill(pid, signal.SIGKILL)  # the other trials are running, one of them on this worker
        killed.append(len(list(directory.glob("trial_*.npz"))))

    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, dashboard_address=None, silence_logs=50
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        victim = sorted(client.run(os.getpid).values())[0]
        killer = threading.Thread(target=kill_one_worker_after_the_first_record, args=(victim,))
        killer.start()
        result = run_campaign(
            small(trials=TRIALS),
            tmp_path,
            executor="dask",
            scheduler=cluster.scheduler_address,
            progress=False,
        )
        killer.join()
        assert victim not in client.run(os.getpid).values()  # it died (its nanny started another)
    assert len(killed) == 1 and killed[0] < TRIALS  # records on disk when the worker died: mid-campaign
    assert result.resumed == 0 and len(result.trials) == TRIALS
    assert_same_records(result.directory, uninterrupted.directory, TRIALS)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkill_of_the_parent_takes_its_dask_workers(tmp_path):
    process = start_campaign(tmp_path, 2, TRIALS, executor="dask")
    wait_for_records(tmp_path / small().name, 1, process)
    children = descendants(process.pid)
    assert len(children) >= 2
    process.kill()
    process.wait(timeout=30)
    assert alive(children, within=10.0) == {}


def test_an_unreachable_scheduler_is_one_prompt_error_naming_it(tmp_path, monkeypatch, capsys):
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{probe.getsockname()[1]}"
    monkeypatch.setattr(executors, "DASK_CONNECT_TIMEOUT", 1.0)  # the mechanism, not the 10 s
    assert executors.DASK_CONNECT_TIMEOUT < 30  # dask's own default: half a minute of silence
    with pytest.raises(SchedulerUnreachable, match=rf"no Dask scheduler answered at {address} within 1 s"):
        run_campaign(small(trials=1), tmp_path, executor="dask", scheduler=address, progress=False)
    code = cli.main(
        ["campaign", *CLI_FLAGS, "--trials", "1", "--executor", "dask"]
        + ["--scheduler", address, "--out", str(tmp_path)]
    )
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and address in err and "--out" not in err
