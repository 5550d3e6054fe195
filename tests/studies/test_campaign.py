"""Monte Carlo campaigns: keying and resume, checked records, faults, the index, config files."""

import errno
import os
import shutil
import signal
import sqlite3
import stat
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from tests.helpers_campaign import CLI_FLAGS, assert_same_records, small
from uuv_ocp import cli
from uuv_ocp.control import faults as uo_faults
from uuv_ocp.studies import campaign as campaign_module
from uuv_ocp.studies import records as records_module
from uuv_ocp.studies.campaign import CampaignConfig, run_campaign
from uuv_ocp.studies.campaign_file import load_campaign_file
from uuv_ocp.studies.records import (
    IndexWarning,
    RecordWarning,
    StorageError,
    query_trials,
    read_record,
    write_record,
)

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """Return the 3-trial campaign run once, in this process, start to end."""
    return run_campaign(small(), tmp_path_factory.mktemp("reference"), workers=1, progress=False)


@pytest.fixture(scope="module")
def other_campaign(tmp_path_factory):
    """Return another campaign (another seed) whose records can be copied over ours."""
    return run_campaign(small(seed=9, trials=2), tmp_path_factory.mktemp("other"), workers=1, progress=False)


def test_more_trials_reuse_the_first_ones_and_match_an_uninterrupted_run(tmp_path, uninterrupted):
    two = run_campaign(small(trials=2), tmp_path, workers=1, progress=False)
    stamps = [p.stat().st_mtime_ns for p in sorted(two.directory.glob("trial_*.npz"))]
    three = run_campaign(small(trials=3), tmp_path, workers=1, progress=False)
    assert three.directory == two.directory and three.resumed == 2
    assert [p.stat().st_mtime_ns for p in sorted(three.directory.glob("trial_*.npz"))][:2] == stamps
    assert_same_records(three.directory, uninterrupted.directory, 3)
    again = run_campaign(small(), tmp_path, workers=1, progress=False)
    assert again.resumed == 3 and again.summary == three.summary
    assert len(query_trials(tmp_path, campaign=three.config.name)) == 3


@pytest.mark.parametrize(
    "change",
    [
        {"horizon": 9},
        {"dt": 0.05},
        {"duration": 2.5},
        {"seed": 4},
        {"solver": "ipopt"},
        {"solver_options": {"max_iter": 5}},
        {"max_current": 0.4},
        {"current_noise": 0.03},
        {"current_decay": 0.2},
        {"current_known": False},
        {"mismatch": False},
        {"noise_std": (0.0,) * 6},
        {"reference": "s3"},
        {"estimator": "ekf"},
    ],
)
def test_every_setting_but_the_trial_count_is_part_of_the_key(change):
    assert small(**change).name != small().name
    assert small(**change).trial_settings(0) != small().trial_settings(0)
    assert small(trials=7).name == small().name


def test_a_campaign_without_an_estimator_keeps_the_key_it_had_before_there_was_one():
    # records written before estimators existed are read back: no estimator, no key entry
    assert "estimator" not in small().settings() and "sensors" not in small().settings()
    assert small(estimator="ekf").settings()["estimator"] == "ekf"


def test_summary_matches_the_trials_and_trials_differ(uninterrupted):
    trials = uninterrupted.trials
    assert trials[0]["max_abs_ey"] != trials[1]["max_abs_ey"]
    assert uninterrupted.summary["trials"] == 3 and uninterrupted.summary["faults"] == 0
    assert uninterrupted.summary["mean_var_ex"] == pytest.approx(np.mean([t["var_ex"] for t in trials]))
    assert uninterrupted.summary["failures"] == sum(t["failures"] for t in trials)


def _truncate(path, other):
    path.write_bytes(path.read_bytes()[:200])


def _empty(path, other):
    path.write_bytes(b"")


def _rewrite(path, change):
    with np.load(path, allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    change(arrays)
    np.savez_compressed(path, **arrays)  # keeps the old checksum


def _nan_fill(path, other):
    _rewrite(path, lambda a: a.update(states=np.full_like(a["states"], np.nan)))


def _alter(path, other):  # finite, the right length: only the checksum tells
    def nudge(a):
        a["states"][5, 0] += 0.1

    _rewrite(path, nudge)


def _shorten(path, other):
    def cut(a):
        for key in ("t", "states", "reference", "currents"):
            a[key] = a[key][:-5]
        for key in (
            "controls",
            "solve_times",
            "iterations",
            "fallback_steps",
            "relaxed_steps",
            "deadline_steps",
        ):
            a[key] = a[key][:-5]
        a["statuses"] = a["statuses"][:-5]

    _rewrite(path, cut)


def _copy_other_trial(path, other):
    shutil.copyfile(path.with_name("trial_0000.npz"), path)


def _copy_other_campaign(path, other):
    shutil.copyfile(other / path.name, path)


def _plain_save(path, other):
    from uuv_ocp import ClosedLoopResult

    ClosedLoopResult.load(str(path)).save(str(path))  # a good run, but without checksum or config


@pytest.mark.parametrize(
    "corrupt",
    [_truncate, _empty, _nan_fill, _alter, _shorten, _copy_other_trial, _copy_other_campaign, _plain_save],
)
def test_a_bad_record_is_reported_by_path_and_recomputed(tmp_path, uninterrupted, other_campaign, corrupt):
    other = other_campaign.directory
    out = tmp_path / "out"
    shutil.copytree(uninterrupted.directory, out / uninterrupted.directory.name)
    victim = out / uninterrupted.directory.name / "trial_0001.npz"
    corrupt(victim, other)
    with pytest.warns(RecordWarning, match=r"trial_0001\.npz"):
        result = run_campaign(small(), out, workers=1, progress=False)
    assert result.recomputed == (1,) and result.resumed == 2
    assert_same_records(result.directory, uninterrupted.directory, 3)
    np.testing.assert_equal(result.summary["mean_max_abs_ex"], uninterrupted.summary["mean_max_abs_ex"])


def test_write_record_leaves_no_temporary_and_read_record_checks_the_configuration(tmp_path, uninterrupted):
    from uuv_ocp import ClosedLoopResult

    run = ClosedLoopResult.load(str(uninterrupted.directory / "trial_0000.npz"))
    path = tmp_path / "run.npz"
    write_record(path, run, {"a": 1})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.npz"]
    loaded, _ = read_record(path, {"a": 1})
    np.testing.assert_array_equal(loaded.states, run.states)
    with pytest.warns(RecordWarning, match=r"another configuration \(a: 1 instead of 2\)"):
        assert read_record(path, {"a": 2}) is None


class _NoiseThatFails(campaign_module.MeasurementNoise):
    def __init__(self, std, fail_at):
        super().__init__(std)
        object.__setattr__(self, "calls", [0])
        object.__setattr__(self, "fail_at", fail_at)

    def sample(self, rng):
        self.calls[0] += 1
        return np.full(len(self.std), np.nan) if self.calls[0] > self.fail_at else super().sample(rng)


def test_a_faulted_trial_is_recorded_counted_and_resumed(tmp_path, uninterrupted, monkeypatch):
    simulate = campaign_module.simulate
    seed_of_trial_0 = campaign_module._trial_setup(small(), 0)[2]

    def faulty(controller, x0, duration, *, noise, seed, **kwargs):
        if seed == seed_of_trial_0:  # the sensor of trial 0 breaks after 7 measurements
            noise = _NoiseThatFails(noise.std, 7)
        return simulate(controller, x0, duration, noise=noise, seed=seed, **kwargs)

    monkeypatch.setattr(campaign_module, "simulate", faulty)
    result = run_campaign(small(), tmp_path, workers=1, progress=False)
    assert "non-finite measurement" in result.faults[0] and result.faults[1:] == (None, None)
    assert result.summary["faults"] == 1 and result.trials[0]["steps"] == 7
    # the means are over the trials that ran to their end: 1 and 2, as in the uninterrupted run
    complete = uninterrupted.trials[1:]
    assert result.summary["mean_max_abs_ex"] == pytest.approx(np.mean([t["max_abs_ex"] for t in complete]))
    assert_same_records(tmp_path / result.config.name, uninterrupted.directory, [1, 2])
    (row,) = query_trials(tmp_path, faulted=True)
    assert row["trial"] == 0 and row["steps"] == 7 and "non-finite" in row["fault"]
    monkeypatch.setattr(campaign_module, "simulate", simulate)
    again = run_campaign(small(), tmp_path, workers=1, progress=False)  # the fault is a result: kept
    assert again.resumed == 3 and again.faults == result.faults


def test_the_index_lists_every_trial_with_its_metrics(tmp_path, uninterrupted):
    rows = query_trials(uninterrupted.directory.parent, campaign=uninterrupted.config.name)
    assert [row["trial"] for row in rows] == [0, 1, 2]
    for row, metrics in zip(rows, uninterrupted.trials, strict=True):
        assert row["max_abs_ex"] == metrics["max_abs_ex"] and row["metrics"]["var_ey"] == metrics["var_ey"]
        assert row["solver"] == "sqp" and row["reference"] == "s2" and row["fault"] is None
        assert row["config"]["trial"] == row["trial"] and row["config"]["horizon"] == 8
    assert query_trials(uninterrupted.directory.parent, solver="ipopt") == []
    assert query_trials(tmp_path) == []


def test_an_unwritable_output_folder_is_one_error_before_any_work(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(ValueError, match="out_dir .*file/campaigns: not a writable folder"):
        run_campaign(small(), blocker / "campaigns", workers=1, progress=False)
    assert cli.main(["campaign", "--trials", "1", "--out", str(blocker / "x")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out" in err and "cannot create the folder" in err


@pytest.mark.parametrize(
    ("changes", "name"),
    [
        ({"trials": 0}, "trials"),
        ({"reference": "s0"}, "s0"),
        ({"duration": -1.0}, "duration"),
        ({"solver": "newton"}, "newton"),
        ({"noise_std": (0.1,) * 5}, "noise_std"),
        ({"vehicle": "bluerov2-heavy"}, "controller_model"),
        ({"dt": 0.0}, "dt"),
        ({"estimator": "kalman"}, "estimator must be one of"),
    ],
)
def test_bad_configuration_raises(changes, name):
    with pytest.raises(ValueError, match=name):
        small(**changes)


def test_bad_executor_arguments_raise(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="executor"):
        run_campaign(small(), tmp_path, executor="threads")
    with pytest.raises(ValueError, match="scheduler is for executor 'dask'"):
        run_campaign(small(), tmp_path, scheduler="tcp://localhost:8786")
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # as if the extra were not installed
    with pytest.raises(ValueError, match=r"pip install 'uuv_ocp\[dask\]'"):
        run_campaign(small(), tmp_path, executor="dask")
    assert not any(tmp_path.iterdir())  # refused before any work


def test_six_dof_campaign_runs_under_a_current(tmp_path):
    config = CampaignConfig(
        vehicle="bluerov2-heavy",
        mismatch=False,
        reference="s2",
        solver="sqp",
        trials=1,
        duration=1.0,
        horizon=5,
        max_current=0.3,
        noise_std=(0.0,) * 12,
    )
    result = run_campaign(config, tmp_path, workers=1, progress=False)
    from uuv_ocp import ClosedLoopResult

    run = ClosedLoopResult.load(str(result.directory / "trial_0000.npz"))
    assert run.states.shape == (11, 12) and run.currents.shape == (11, 3)
    assert np.all(np.hypot(run.currents[:, 0], run.currents[:, 1]) > 0) and np.all(run.currents[:, 2] == 0)
    assert result.summary["faults"] == 0


def test_cli_campaign(tmp_path, capsys):
    code = cli.main(
        ["campaign", "--trials", "1", "--duration", "0.3", "--workers", "1", "--out", str(tmp_path)]
    )
    assert code == 0
    assert "1 trials" in capsys.readouterr().out
    assert cli.main(["campaign", "--solver", "newton", "--out", str(tmp_path)]) == 2


def test_the_example_campaign_file_runs_at_reduced_size(tmp_path, capsys):
    example = load_campaign_file(ROOT / "examples" / "campaign.toml")
    assert len(example.configs) >= 2 and len({c.solver for c in example.configs}) == len(example.configs)
    text = (ROOT / "examples" / "campaign.toml").read_text()
    reduced = tmp_path / "quick.toml"
    reduced.write_text(
        text.replace(f"trials = {example.configs[0].trials}", "trials = 1")
        .replace(f"duration = {example.configs[0].duration}", "duration = 1.0")
        .replace(f"horizon = {example.configs[0].horizon}", "horizon = 6")
    )
    quick = load_campaign_file(reduced)
    assert [c.trials for c in quick.configs] == [1] * len(quick.configs)
    out = tmp_path / "out"
    assert cli.main(["campaign", "--config", str(reduced), "--workers", "1", "--out", str(out)]) == 0
    table = (out / "quick_summary.txt").read_text()
    for config in quick.configs:
        assert config.solver in table and (out / config.name / "trial_0000.npz").exists()
        assert load_campaign_file(out / config.name / "config.toml").configs[0] == config
    assert (out / "quick.toml").read_text() == reduced.read_text()


def test_a_campaign_file_names_an_estimator_and_writes_it_back(tmp_path):
    from uuv_ocp.studies.campaign import to_toml

    path = tmp_path / "ekf.toml"
    path.write_text(
        '[campaign]\nreference = "s2"\nsolver = "sqp"\n'
        '[disturbance]\ncurrent_known = false\nestimator = "ekf"\n'
    )
    (config,) = load_campaign_file(path).configs
    assert config.estimator == "ekf" and not config.current_known
    again = tmp_path / "again.toml"
    again.write_text(to_toml([config]))
    assert load_campaign_file(again).configs == (config,)
    assert "estimator" not in to_toml([small()])  # none: the key is left out, as before


def test_a_campaign_file_with_an_unknown_key_is_one_error_naming_it(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[campaign]\nreference = "s2"\ntrails = 3\n')
    assert cli.main(["campaign", "--config", str(bad), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown key 'campaign.trails'" in err and "bad.toml" in err
    bad.write_text('[campaign]\nreference = "s2"\n[disturbances]\nmax_current = 1\n')
    assert cli.main(["campaign", "--config", str(bad), "--out", str(tmp_path)]) == 2
    assert "unknown key 'disturbances'" in capsys.readouterr().err


def test_any_vehicle_and_path_from_files_and_the_key_follows_their_content(tmp_path):
    vehicle = tmp_path / "rov.toml"
    vehicle.write_text((ROOT / "examples" / "vehicles" / "light_rov.toml").read_text())
    path = f"waypoints {ROOT / 'examples' / 'paths' / 'survey.csv'}"
    config = small(vehicle=str(vehicle), controller_model="rexrov", reference=path, trials=1)
    result = run_campaign(config, tmp_path / "out", workers=1, progress=False)
    assert result.summary["faults"] == 0 and result.trials[0]["steps"] == 20
    assert result.config.settings()["plant_content"].mass == 1200.0
    # the same spec, another vehicle
    vehicle.write_text(vehicle.read_text().replace("mass = 1200.0", "mass = 1300.0"))
    edited = small(vehicle=str(vehicle), controller_model="rexrov", reference=path, trials=1)
    assert edited.name != config.name


def test_cli_dask_without_the_extra_is_one_line_saying_how_to_install(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    assert cli.main(["campaign", "--trials", "1", "--executor", "dask", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install 'uuv_ocp[dask]'" in err
    assert not any(tmp_path.iterdir())


def test_several_campaigns_on_one_executor_give_each_its_own_records(tmp_path, uninterrupted, other_campaign):
    from uuv_ocp.studies.campaign import run_campaigns

    ours, other = run_campaigns([small(), small(seed=9, trials=2)], tmp_path, workers=2, progress=False)
    assert_same_records(ours.directory, uninterrupted.directory, 3)
    assert_same_records(other.directory, other_campaign.directory, 2)
    assert ours.summary["mean_max_abs_ex"] == uninterrupted.summary["mean_max_abs_ex"]
    with pytest.raises(ValueError, match="same campaign twice"):
        run_campaigns([small(), small(trials=5)], tmp_path)


def test_the_process_alias_runs_the_pool_even_for_one_worker(tmp_path, uninterrupted, monkeypatch):
    def no_simulation_in_this_process(*args, **kwargs):
        raise AssertionError("the trial ran in the driver")

    # a spawned worker imports its own, unpatched module
    monkeypatch.setattr(campaign_module, "simulate", no_simulation_in_this_process)
    result = run_campaign(small(trials=1), tmp_path, executor="process", workers=1, progress=False)
    assert_same_records(result.directory, uninterrupted.directory, 1)


# ---------------------------------------------------------------- damaged, locked, full, not a file
def _garbage_index(path):
    path.write_bytes(b"\x00garbage, not SQLite\xff" * 200)


def _truncated_index(path):
    path.write_bytes(path.read_bytes()[:5000])  # mid-page: SQLite's header promises more


def _index_of_another_schema(path):
    path.unlink()
    connection = sqlite3.connect(path)
    connection.execute("CREATE TABLE trials (path TEXT PRIMARY KEY, score REAL)")
    connection.commit()
    connection.close()


def _fifo_index(path):
    path.unlink()
    os.mkfifo(path)


@pytest.fixture
def two_campaigns(tmp_path, uninterrupted, other_campaign):
    """Return an output folder holding both campaigns' records and their index."""
    out = tmp_path / "out"
    shutil.copytree(uninterrupted.directory, out / uninterrupted.directory.name)
    shutil.copytree(other_campaign.directory, out / other_campaign.directory.name)
    for campaign in (small(), small(seed=9, trials=2)):  # index them as the campaigns did
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IndexWarning)
            run_campaign(campaign, out, workers=1, progress=False)
    assert len(query_trials(out)) == 5
    return out


@pytest.fixture
def no_hang():
    """Fail (instead of hanging for good) when the test body blocks for more than 120 s."""

    def timeout(signum, frame):
        raise AssertionError("blocked for 120 s")

    previous = signal.signal(signal.SIGALRM, timeout)
    signal.alarm(120)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)


@pytest.mark.parametrize("damage", [_garbage_index, _truncated_index, _index_of_another_schema, _fifo_index])
def test_a_damaged_index_is_moved_aside_and_rebuilt_from_every_campaigns_records(
    two_campaigns, uninterrupted, damage, no_hang
):
    out = two_campaigns
    index = out / "index.sqlite"
    damage(index)
    kept = None if stat.S_ISFIFO(index.lstat().st_mode) else index.read_bytes()
    with pytest.raises(StorageError, match=r"index\.sqlite is damaged .*the next campaign run"):
        query_trials(out)  # a reader says so (and does not block on a FIFO)
    with pytest.warns(IndexWarning, match=r"damaged .*moved aside to index\.sqlite\.damaged-"):
        result = run_campaign(small(), out, workers=1, progress=False)
    assert result.resumed == 3 and not result.recomputed
    (aside,) = [p for p in out.glob("index.sqlite.damaged-*") if not p.name.endswith(("-wal", "-shm"))]
    assert kept is None or aside.read_bytes() == kept  # kept as it was, for inspection
    rows = query_trials(out)  # the other campaign's rows too: rebuilt from its records
    assert [(row["campaign"], row["trial"]) for row in rows] == sorted(
        [(uninterrupted.config.name, i) for i in range(3)] + [(small(seed=9).name, i) for i in range(2)]
    )
    ours = [row for row in rows if row["campaign"] == uninterrupted.config.name]
    assert [row["max_abs_ex"] for row in ours] == [t["max_abs_ex"] for t in uninterrupted.trials]


def test_the_command_line_says_in_one_line_that_it_rebuilt_the_index(two_campaigns, capsys):
    _garbage_index(two_campaigns / "index.sqlite")
    code = cli.main([*_CLI_SMALL, "--out", str(two_campaigns)])
    err = capsys.readouterr().err
    assert code == 0, err
    (line,) = [line for line in err.splitlines() if "index" in line]
    assert line.startswith("warning: index ") and "rebuilt from 5 records" in line


_CLI_SMALL = ["campaign", *CLI_FLAGS, "--trials", "3", "--workers", "1"]


@pytest.fixture
def locked_index(two_campaigns, monkeypatch):
    """Hold a write transaction on the index (as an sqlite3 shell left in BEGIN would)."""
    monkeypatch.setattr(records_module, "BUSY_TIMEOUT", 0.2)  # the mechanism, not the 5 s
    holder = sqlite3.connect(two_campaigns / "index.sqlite", isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    yield two_campaigns
    holder.rollback()
    holder.close()


def test_a_locked_index_is_one_clear_error_naming_who_holds_it(locked_index, capsys):
    assert records_module.BUSY_TIMEOUT <= 10  # prompt, not a minute  # noqa: PLR2004
    with pytest.raises(StorageError, match=r"index .*index\.sqlite is locked") as caught:
        run_campaign(small(), locked_index, workers=1, progress=False)
    assert f"pid {os.getpid()} " in str(caught.value)  # this test process holds it
    assert cli.main([*_CLI_SMALL, "--out", str(locked_index)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: index ") and "locked" in err


def _enospc_on_call(monkeypatch, failing_call):
    save, calls = np.savez_compressed, [0]

    def full_disk(*args, **kwargs):
        calls[0] += 1
        if calls[0] == failing_call:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return save(*args, **kwargs)

    monkeypatch.setattr(np, "savez_compressed", full_disk)


def test_a_full_disk_is_one_clear_error_and_loses_nothing_already_written(
    tmp_path, uninterrupted, monkeypatch, capsys
):
    _enospc_on_call(monkeypatch, 2)  # trial 0 is written, trial 1's write finds the disk full
    directory = tmp_path / small().name
    with pytest.raises(StorageError, match=r"No space left on device; free space") as caught:
        run_campaign(small(), tmp_path, workers=1, progress=False)
    assert f"trial_0001.npz in {directory}" in str(caught.value) and caught.value.errno == errno.ENOSPC
    assert sorted(p.name for p in directory.iterdir()) == ["trial_0000.npz"]  # no half-written file
    assert read_record(directory / "trial_0000.npz", small().trial_settings(0), steps=small().steps())
    assert [row["trial"] for row in query_trials(tmp_path)] == [0]
    _enospc_on_call(monkeypatch, 1)
    assert cli.main([*_CLI_SMALL, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(directory) in err and "No space left" in err
    monkeypatch.undo()  # the disk has room again
    resumed = run_campaign(small(), tmp_path, workers=1, progress=False)
    assert resumed.resumed == 1 and not resumed.recomputed
    assert_same_records(directory, uninterrupted.directory, 3)


def test_a_full_disk_under_the_index_is_one_clear_error(two_campaigns, monkeypatch):
    connect = records_module._raw_connect

    def no_room_to_grow(path):  # SQLite's own SQLITE_FULL: the file may not grow by one page
        connection = connect(path)
        pages = connection.execute("PRAGMA page_count").fetchone()[0]
        connection.execute(f"PRAGMA max_page_count = {pages}")
        return connection

    filler = sqlite3.connect(two_campaigns / "index.sqlite")  # the last free byte of every page taken
    filler.execute("CREATE TABLE filler (x BLOB)")
    filler.execute("INSERT INTO filler VALUES (zeroblob(100000))")
    filler.commit()
    filler.execute("VACUUM")
    filler.close()
    monkeypatch.setattr(records_module, "_raw_connect", no_room_to_grow)
    with pytest.raises(StorageError, match=r"cannot write index .*: no space left in ") as caught:
        run_campaign(small(trials=4), two_campaigns, workers=1, progress=False)
    assert caught.value.errno == errno.ENOSPC
    assert (two_campaigns / small().name / "trial_0003.npz").exists()  # the record went first


def _fifo(path):
    os.mkfifo(path)


def _directory(path):
    path.mkdir()
    (path / "inside.txt").write_text("kept")


@pytest.mark.parametrize(("make", "kind"), [(_fifo, "a FIFO"), (_directory, "a directory")])
def test_a_fifo_or_directory_at_a_record_path_is_set_aside_and_recomputed(
    tmp_path, uninterrupted, make, kind, no_hang
):
    out = tmp_path / "out"
    shutil.copytree(uninterrupted.directory, out / uninterrupted.directory.name)
    victim = out / uninterrupted.directory.name / "trial_0001.npz"
    victim.unlink()
    make(victim)
    with pytest.warns(RecordWarning, match=rf"trial_0001\.npz: {kind}.*not a record file; moved aside to "):
        result = run_campaign(small(), out, workers=1, progress=False)
    assert result.recomputed == (1,) and result.resumed == 2
    assert_same_records(result.directory, uninterrupted.directory, 3)
    (aside,) = victim.parent.glob("trial_0001.npz.damaged-*")
    assert aside.is_dir() == (kind == "a directory")


def test_writing_a_record_over_a_directory_names_the_path(tmp_path, uninterrupted):
    from uuv_ocp import ClosedLoopResult

    run = ClosedLoopResult.load(str(uninterrupted.directory / "trial_0000.npz"))
    (tmp_path / "run.npz").mkdir()
    with pytest.raises(StorageError, match=r"a directory is in the way at .*run\.npz"):
        write_record(tmp_path / "run.npz", run, {"a": 1})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.npz"]


def test_a_missing_index_is_rebuilt_from_every_campaigns_records_silently(two_campaigns):
    (two_campaigns / "index.sqlite").unlink()  # e.g. a campaign killed between a record and its row
    with warnings.catch_warnings():
        warnings.simplefilter("error", IndexWarning)
        result = run_campaign(small(), two_campaigns, workers=1, progress=False)
    assert result.resumed == 3
    assert (
        len(query_trials(two_campaigns)) == 5
        and len(query_trials(two_campaigns, campaign=small(seed=9).name)) == 2
    )


@pytest.mark.parametrize("code", [264, 776])  # SQLITE_READONLY_RECOVERY, SQLITE_READONLY_ROLLBACK
def test_an_index_a_read_only_connection_cannot_recover_is_recovered_not_refused(
    two_campaigns, monkeypatch, code
):
    """A campaign killed mid-write can leave a WAL whose recovery needs a writer.

    Seen once in ~30 SIGKILL runs (``test_campaign_processes.py``): the read-only check got
    "attempt to write a readonly database" (a SQLITE_READONLY code) and the resume stopped.
    The read-only connection is made to fail the same way here; the check must then recover
    the index with a writer's connection and resume, keeping every row.
    """
    inspect = records_module._inspect

    def read_only_cannot_recover(uri):
        if "mode=ro" in uri:
            error = sqlite3.OperationalError("attempt to write a readonly database")
            error.sqlite_errorcode = code
            raise error
        return inspect(uri)

    monkeypatch.setattr(records_module, "_inspect", read_only_cannot_recover)
    with warnings.catch_warnings():
        warnings.simplefilter("error", IndexWarning)  # recovered, not set aside as damaged
        result = run_campaign(small(), two_campaigns, workers=1, progress=False)
    assert result.resumed == 3 and not result.recomputed
    assert len(query_trials(two_campaigns)) == 5


def test_the_resume_sweeps_temporaries_of_dead_writers_on_this_host_only(tmp_path):
    """A writer SIGKILLed mid-write leaves its temporary file; only provably dead ones go."""
    import socket
    import subprocess

    from uuv_ocp.studies.records import sweep_temporaries

    dead = subprocess.Popen([sys.executable, "-c", "pass"])  # a pid that has ended
    dead.wait()
    host = socket.gethostname()
    names = {
        "dead": f".trial_0001.{host}-{dead.pid}.ab12cd_3.tmp",
        "alive": f".trial_0002.{host}-{os.getpid()}.zz99yy00.tmp",  # this process: a live writer
        "remote": f".trial_0003.other-host.example-{dead.pid}.ab12cd_3.tmp",  # unknown to this host
        "foreign": ".index.sqlite.tmp",  # not a record's
    }
    for name in names.values():
        (tmp_path / name).write_bytes(b"half a record")
    assert sweep_temporaries(tmp_path) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(n for k, n in names.items() if k != "dead")


def _fault_campaign(**changes):
    settings = {
        "vehicle": "bluerov2-heavy-thrusters",
        "mismatch": False,
        "reference": "hold 0,0,0",
        "solver": "sqp",
        "trials": 2,
        "duration": 1.0,
        "horizon": 5,
        "max_current": 0.3,
        "noise_std": (0.0,) * 12,
        "faults": uo_faults.RandomFaults(count=2, window=(0.2, 0.6), kinds=("failed", "loss", "stuck")),
    }
    return CampaignConfig(**{**settings, **changes})


def test_a_trials_faults_follow_its_seed_and_its_record_holds_them(tmp_path):
    """Trial i's faults are RandomFaults.draw on default_rng([seed, i, 27]); the plant flies them."""
    config = _fault_campaign()
    problem = config.problem()
    for index in range(2):
        expected = config.faults.draw(
            np.random.default_rng([config.seed, index, 27]),
            problem.vehicle.control_bound,
            t0=problem.reference.t_start,
        )
        assert campaign_module.trial_faults(config, index) == expected
        assert config.trial_settings(index)["faults_drawn"] == [
            {
                "thruster": f.thruster,
                "time": f.time,
                "kind": f.kind,
                "effectiveness": f.effectiveness,
                "value": f.value,
            }
            for f in expected
        ]
    assert campaign_module.trial_faults(config, 0) != campaign_module.trial_faults(config, 1)
    # the trial's current is the fault-free campaign's (the faults draw from their own stream)
    assert (
        campaign_module._trial_setup(config, 1)[0]
        == campaign_module._trial_setup(_fault_campaign(faults=None), 1)[0]
    )
    result = run_campaign(config, tmp_path, workers=1, progress=False)
    from uuv_ocp import ClosedLoopResult

    for index in range(2):
        run = ClosedLoopResult.load(str(result.directory / f"trial_{index:04d}.npz"))
        health = np.ones((run.controls.shape[0], 8))
        for fault in campaign_module.trial_faults(config, index):  # the schedule, on the step grid
            first = int(np.ceil((fault.time - run.t[0]) / config.dt - 1e-9))
            health[first:, fault.thruster] = fault.health
        np.testing.assert_array_equal(run.thruster_health, health)
    again = run_campaign(config, tmp_path, workers=1, progress=False)
    assert again.resumed == 2


def test_a_campaign_file_faults_table_reads_back(tmp_path):
    from uuv_ocp.studies.campaign import to_toml

    path = tmp_path / "faults.toml"
    path.write_text(
        '[campaign]\nvehicle = "bluerov2-heavy-thrusters"\nreference = "s2"\nsolver = "sqp"\nhorizon = 5\n'
        '[disturbance]\nmismatch = false\ncurrent_known = false\nestimator = "ekf"\n'
        "noise_std = [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]\n"
        '[faults]\ncount = 2\nwindow = [3.0, 9.0]\nkinds = ["stuck"]\nfault_tolerant = true\n'
    )
    (config,) = load_campaign_file(path).configs
    assert config.faults == uo_faults.RandomFaults(count=2, window=(3.0, 9.0), kinds=("stuck",))
    assert config.fault_tolerant
    again = tmp_path / "again.toml"
    again.write_text(to_toml([config]))
    assert load_campaign_file(again).configs == (config,)
    assert "[faults]" not in to_toml([small()])
    assert "faults" not in small().settings()  # campaigns without faults keep their key


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"vehicle": "bluerov2-heavy"}, "faults needs a vehicle whose controls are thruster forces"),
        ({"faults": {"count": 9}}, "faults.count must be at most"),
        ({"faults": {"cuont": 1}}, "faults: .*cuont"),
        ({"faults": None, "fault_tolerant": True}, "fault_tolerant needs an estimator"),
        ({"faults": 1}, "faults must be a uuv_ocp.RandomFaults"),
    ],
)
def test_bad_fault_configuration_raises(changes, match):
    with pytest.raises(ValueError, match=match):
        _fault_campaign(**changes)


@pytest.mark.parametrize(
    "flags",
    [
        ["--faults", "one"],
        ["--faults", "-1"],
        ["--faults", "1", "--fault-kinds", "broken"],
        ["--faults", "1", "--fault-window", "9,3"],
        ["--faults", "1", "--fault-window", "soon"],
        ["--faults", "1", "--estimator", "kalman"],
    ],
)
def test_cli_bad_fault_flags_are_one_line_and_exit_2(tmp_path, capsys, flags):
    argv = ["campaign", "--vehicle", "bluerov2-heavy-thrusters", "--no-mismatch", "--estimator", "ekf"]
    assert cli.main([*argv, *flags, "--trials", "1", "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert error.startswith("error: ") and error.count("\n") == 1
    assert "--faults" in error or "--fault-" in error or "--estimator" in error
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
