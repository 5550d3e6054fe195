"""Command line and the resumable reproduction job."""

import pytest

import uuv_ocp as uo
from uuv_ocp import cli
from uuv_ocp.reference.path import PAPER_REFERENCES
from uuv_ocp.studies.compare import track_references


def test_solvers_lists_names(capsys):
    assert cli.main(["solvers"]) == 0
    names = capsys.readouterr().out.split()
    assert {"ipopt", "sqp", "fatrop", "igwo", "igwo+ipopt"} <= set(names)


def test_track_writes_figures_and_resumes(tmp_path, capsys):
    assert cli.main(["track", "-r", "s2", "--duration", "1.0", "--out", str(tmp_path)]) == 0
    output = capsys.readouterr().out
    assert "s2" in output and "ipopt" in output
    for name in ("s2_xoy.png", "s2_errors.png"):
        assert (tmp_path / name).exists()
    (record,) = (tmp_path / "runs").glob("s2_ipopt_*.npz")
    saved = record.stat().st_mtime_ns
    rows = track_references(["s2"], out_dir=tmp_path, duration=1.0, progress=False, figures=False)
    assert record.stat().st_mtime_ns == saved  # resumed, not rerun
    assert rows[0].metrics["steps"] == 10


def test_track_reuses_a_saved_run_only_for_the_same_configuration(tmp_path):
    # the issue: after `make demo`, `track -r s2 --horizon 5 --dt 0.2 --duration 12` printed the demo's row
    first = track_references(
        ["s2"], "sqp", out_dir=tmp_path, duration=1.0, horizon=8, progress=False, figures=False
    )
    other = track_references(
        ["s2"], "sqp", out_dir=tmp_path, duration=1.2, horizon=5, dt=0.2, progress=False, figures=False
    )
    assert len(list((tmp_path / "runs").glob("s2_sqp_*.npz"))) == 2
    assert other[0].metrics["steps"] == 6 and first[0].metrics["steps"] == 10
    again = track_references(
        ["s2"], "sqp", out_dir=tmp_path, duration=1.2, horizon=5, dt=0.2, progress=False, figures=False
    )
    assert again[0].metrics["max_abs_ex"] == other[0].metrics["max_abs_ex"]
    assert len(list((tmp_path / "runs").glob("s2_sqp_*.npz"))) == 2


def test_bad_arguments_exit_with_a_message(capsys):
    assert cli.main(["track", "-r", "s42"]) == 2
    assert "s42" in capsys.readouterr().err
    assert cli.main(["track", "-s", "newton"]) == 2
    assert "newton" in capsys.readouterr().err
    assert cli.main(["compare", "--solvers", "newton"]) == 2


def _replay(vehicle, run):
    """Integrate the saved controls through ``vehicle`` with scipy's RK45 (a second integrator)."""
    import numpy as np
    from scipy.integrate import solve_ivp

    rhs = vehicle.model_function()  # the vehicle protocol's dynamics (built-ins and a user's)
    state = run.states[0]
    for k, control in enumerate(run.controls):
        step = solve_ivp(
            lambda _, x, u=control: np.asarray(rhs(x, u, np.zeros(2))).ravel(),
            (run.t[k], run.t[k + 1]),
            state,
            rtol=1e-10,
            atol=1e-10,
        )
        state = step.y[:, -1]
    return state


def test_track_any_vehicle_file_and_waypoint_file(tmp_path, capsys):
    """A TOML vehicle on a CSV waypoint path: the saved run is that vehicle flying that path."""
    import numpy as np

    from uuv_ocp.control.simulation import ClosedLoopResult
    from uuv_ocp.specs import vehicle_from_spec

    vehicle_file = tmp_path / "light.toml"
    vehicle_file.write_text('[vehicle]\npreset = "rexrov"\nname = "light-rov"\nmass = 900.0\n')
    path_file = tmp_path / "legs.csv"
    path_file.write_text("0, 0\n6, 0\n6, 6\n")
    argv = ["track", "--vehicle", str(vehicle_file), "-r", "waypoints", str(path_file), "-s", "IPOPT"]
    argv += ["--duration", "1.0", "--horizon", "5", "--out", str(tmp_path / "out")]
    assert cli.main(argv) == 0
    output = capsys.readouterr().out
    assert "light-rov" in output and "legs" in output and "solver ipopt" in output
    for name in ("legs_xoy.png", "legs_errors.png", "legs_thrust.png", "legs_states.png"):
        assert (tmp_path / "out" / name).exists(), name
    (saved,) = (tmp_path / "out" / "runs").glob("legs*.npz")
    run = ClosedLoopResult.load(str(saved))
    assert run.solver == "ipopt" and len(run.controls) == 10
    np.testing.assert_allclose(run.states[0][:2], [0.0, 0.0], atol=1e-12)  # starts on the first waypoint
    # the plant was the file's vehicle (900 kg), not the RexROV preset (1862.87 kg)
    np.testing.assert_allclose(_replay(vehicle_from_spec(vehicle_file), run), run.states[-1], atol=1e-6)
    assert not np.allclose(_replay(vehicle_from_spec("rexrov"), run), run.states[-1], atol=1e-4)


def test_track_six_dof_vehicle_flies_a_paper_reference_at_depth(tmp_path, capsys):
    import numpy as np

    from uuv_ocp.control.simulation import ClosedLoopResult
    from uuv_ocp.specs import DEFAULT_DEPTH

    argv = ["track", "--vehicle", "bluerov2-heavy", "-r", "s2", "--duration", "0.5", "--horizon", "5"]
    assert cli.main([*argv, "--out", str(tmp_path)]) == 0
    output = capsys.readouterr().out
    assert "bluerov2" in output.lower()
    (saved,) = (tmp_path / "runs").glob("s2*.npz")
    run = ClosedLoopResult.load(str(saved))
    assert run.states.shape == (6, 12)
    np.testing.assert_allclose(run.reference[:, 2], DEFAULT_DEPTH, atol=1e-12)
    # reported as 6-DOF: the depth error, from the run's own arrays, and the speed flag
    header, _, row = output.splitlines()[-5:-2]
    titles = header.split()
    cells = row.split()
    depth = np.max(np.abs(run.states[:, 2] - run.reference[:, 2]))
    assert cells[titles.index("max|ez|")] == f"{depth:.3f}"
    assert "path speed > 1.11 m/s" in row  # s2 peaks at 1.12 m/s; the BlueROV2 Heavy tops out below


def test_solver_names_are_case_insensitive():
    import uuv_ocp as uo
    from uuv_ocp.solvers import REGISTRY

    assert REGISTRY.resolve("IPOPT") == "ipopt"
    assert REGISTRY.resolve("IGWO+Fatrop") == "igwo+fatrop"
    assert REGISTRY.resolve("Multistart-SQP") == "multistart-sqp"
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=5)
    assert uo.NMPC(problem, "SQP").solver_name == "sqp"
    assert uo.get_solver(problem, "SQP") is uo.get_solver(problem, "sqp")  # one per name (and thread)


def test_solvers_name_prints_that_backends_declared_options(capsys):
    from uuv_ocp.solvers.catalog import declared_options

    assert cli.main(["solvers", "Fatrop"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| `")]
    assert [row.split("`")[1] for row in rows] == [option.name for option in declared_options("fatrop")]
    assert cli.main(["solvers", "fatrp"]) == 2
    assert "did you mean 'fatrop'" in capsys.readouterr().err


def test_track_recomputes_a_corrupted_saved_run_and_names_it(tmp_path):
    import numpy as np
    import pytest

    from uuv_ocp.studies.records import RecordWarning

    first = track_references(
        ["s2"], "sqp", out_dir=tmp_path, duration=1.0, horizon=8, progress=False, figures=False
    )
    (record,) = (tmp_path / "runs").glob("s2_sqp_*.npz")
    record.write_bytes(record.read_bytes()[:300])  # truncated, as by a full disk
    with pytest.warns(RecordWarning, match=record.name):
        again = track_references(
            ["s2"], "sqp", out_dir=tmp_path, duration=1.0, horizon=8, progress=False, figures=False
        )
    np.testing.assert_equal(again[0].metrics["max_abs_ex"], first[0].metrics["max_abs_ex"])


def _one_error_line(capsys) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err
    return lines[0]


def test_a_mistyped_subcommand_or_flag_gets_the_nearest_one(capsys):
    assert cli.main(["trak", "-r", "s2"]) == 2
    assert "did you mean 'track'?" in _one_error_line(capsys)
    assert cli.main(["track", "--refrence", "s2"]) == 2
    line = _one_error_line(capsys)
    assert "--refrence" in line and "did you mean --reference?" in line
    assert cli.main(["track", "--duraton", "3", "--sovler", "sqp"]) == 2
    line = _one_error_line(capsys)
    assert "--duration for --duraton" in line and "--solver for --sovler" in line
    assert cli.main(["demo", "--quite"]) == 2
    assert "did you mean --quiet?" in _one_error_line(capsys)
    assert cli.main(["campaign", "--executor", "dsak"]) == 2
    assert "did you mean 'dask'?" in _one_error_line(capsys)
    assert cli.main(["track", "--zzzz"]) == 2  # nothing near: no guess
    assert "did you mean" not in _one_error_line(capsys)


def test_track_current_flag_is_validated_before_anything_runs(capsys, monkeypatch, tmp_path):
    def must_not_run(*args, **kwargs):
        raise AssertionError("a run started on a bad --current")

    monkeypatch.setattr(cli, "track_references", must_not_run)
    for value in ("0.3", "0.3,1,2", "a,b", "--current=-1,0", "nan,1", "0.3,inf", "3,0"):
        flag = [value] if value.startswith("--") else ["--current", value]
        assert cli.main(["track", "-r", "s2", "--out", str(tmp_path), *flag]) == 2
        assert _one_error_line(capsys).startswith("error: --current"), value


def test_track_current_reaches_the_plant_and_the_record_key(tmp_path, capsys):
    import numpy as np

    from uuv_ocp.control.simulation import ClosedLoopResult

    out = str(tmp_path)
    assert (
        cli.main(["track", "-r", "s2", "--duration", "0.3", "--current", "0.3,1.2", "-q", "--out", out]) == 0
    )
    assert "constant current 0.3 m/s towards 1.2 rad" in capsys.readouterr().out
    (record,) = (tmp_path / "runs").glob("s2_ipopt_*.npz")
    run = ClosedLoopResult.load(record)
    np.testing.assert_allclose(
        run.currents, np.tile([0.3 * np.cos(1.2), 0.3 * np.sin(1.2)], (4, 1)), atol=1e-12
    )
    # still water is another configuration: its own record, not the current's
    assert cli.main(["track", "-r", "s2", "--duration", "0.3", "-q", "--out", out]) == 0
    assert len(list((tmp_path / "runs").glob("s2_ipopt_*.npz"))) == 2


def test_track_and_demo_show_progress_where_bars_are_drawn_unless_quiet(capsys, monkeypatch, tmp_path):
    from uuv_ocp.control.disturbances import Current
    from uuv_ocp.progress import ENVIRONMENT_VARIABLE

    calls = []

    def fake(names, solver, **options):
        calls.append((list(names), options["progress"], options["current"], options["estimator"]))
        return []

    monkeypatch.setattr(cli, "track_references", fake)
    monkeypatch.setenv(ENVIRONMENT_VARIABLE, "always")  # capsys's stderr is no terminal
    assert cli.main(["track", "-r", "s2", "s3", "--current", "0.2,0", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert "[1/2] s2 with ipopt" in err and "[2/2] s3 with ipopt" in err
    assert [call[1] for call in calls] == [True, True]
    assert calls[0][2] == Current(speed=0.2, direction=0.0)
    calls.clear()
    assert cli.main(["track", "-r", "s2", "--quiet", "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().err == "" and calls == [(calls[0][0], False, None, None)]
    calls.clear()
    assert cli.main(["demo", "-q", "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().err == "" and len(calls) == 11 and not any(call[1] for call in calls)
    # the realistic loop on the ten references (current unknown, EKF), then the oracle on s2
    assert [call[0] for call in calls] == [[name] for name in PAPER_REFERENCES] + [["s2"]]
    assert [call[3] for call in calls] == ["ekf"] * 10 + [None]
    assert all(call[2] == Current(speed=0.5, direction=1.0) for call in calls)
    monkeypatch.setenv(ENVIRONMENT_VARIABLE, "auto")  # not a terminal: silent, as the bars are
    assert cli.main(["track", "-r", "s2", "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().err == ""


def test_track_reports_a_storage_error_in_one_line(tmp_path, capsys, monkeypatch):
    # a full disk while the run is saved: one line naming the file, exit 2 (was "...: " with
    # the --out prefix and an empty file name, the message of an ordinary OSError)
    from uuv_ocp.studies import compare
    from uuv_ocp.studies.records import StorageError

    def full_disk(path, *args, **kwargs):
        raise StorageError(f"cannot write the run {path}: no space left on device", 28)

    monkeypatch.setattr(compare, "write_record", full_disk)
    code = cli.main(["track", "-r", "s2", "--duration", "0.3", "--horizon", "5", "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "no space left on device" in err[0] and "--out" not in err[0], err


USER_VEHICLE = "examples/vehicles/vessel4dof.py:Vessel4DOF"


def test_track_a_users_vehicle_class_from_its_file(tmp_path, capsys):
    """``--vehicle FILE.py:CLASS``: the saved run is that 8-state vessel flying the path."""
    from pathlib import Path

    import numpy as np

    from uuv_ocp.control.simulation import ClosedLoopResult
    from uuv_ocp.specs import vehicle_from_spec

    spec = str(Path(__file__).resolve().parents[1] / USER_VEHICLE)
    argv = ["track", "--vehicle", spec, "-r", "s2", "-s", "ipopt", "--duration", "0.5", "--horizon", "5"]
    assert cli.main([*argv, "--out", str(tmp_path), "--quiet"]) == 0
    assert "vessel4dof" in capsys.readouterr().out
    (saved,) = (tmp_path / "runs").glob("s2*.npz")
    run = ClosedLoopResult.load(str(saved))
    assert run.states.shape == (6, 8) and run.state_roles[:3] == ("x", "y", "psi")
    # starts on the path's pose at rest, as the vessel's layout maps it: roll zero too
    vessel = vehicle_from_spec(spec)
    pose = uo.Reference.paper("s2").evaluate(np.array([0.0]))[0, :3]
    np.testing.assert_array_equal(run.states[0], [*pose, 0.0, 0.0, 0.0, 0.0, 0.0])
    # the plant was the file's vessel: scipy's RK45 through its model_function() gives the run
    np.testing.assert_allclose(_replay(vessel, run), run.states[-1], atol=1e-6)


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("missing.py:Vessel", "does not exist"),
        ("examples/vehicles/vessel4dof.py:Nothing", "has no class 'Nothing'"),
        ("examples/vehicles/vessel4dof.py:dataclass", "must implement uuv_ocp.VehicleModel"),
    ],
)
def test_a_bad_vehicle_class_is_one_line_and_exit_2(spec, message, capsys, monkeypatch):
    from pathlib import Path

    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    assert cli.main(["track", "--vehicle", spec, "-r", "s2", "--duration", "0.5"]) == 2
    error = capsys.readouterr().err.strip()
    assert message in error and len(error.splitlines()) == 1


def test_track_with_an_estimator_runs_the_realistic_loop_and_says_so(tmp_path, capsys):
    import numpy as np

    from uuv_ocp.control.simulation import ClosedLoopResult

    out = str(tmp_path)
    flags = ["track", "-r", "s2", "--duration", "0.5", "--horizon", "5", "--current", "0.3,1.2", "-q"]
    assert cli.main([*flags, "--estimator", "ekf", "--out", out]) == 0
    printed = capsys.readouterr().out
    assert "(unknown to the controller)" in printed
    assert "estimated by an EKF from position 1 Hz, dvl 5 Hz, attitude 10 Hz, gyro 10 Hz" in printed
    header, _, row = printed.split("ms\n", 1)[1].splitlines()[:3]
    assert header.split()[:3] == ["ref", "solver", "loop"] and row.split()[:3] == ["s2", "ipopt", "ekf"]
    (record,) = (tmp_path / "runs").glob("s2_ipopt_*.npz")
    run = ClosedLoopResult.load(record)
    assert run.measurements.sensors == ("position", "dvl", "attitude", "gyro")
    # the run logged the EKF's current (started from zero: in 0.5 s it is not yet the truth)
    estimated = run.estimates.currents
    assert estimated.shape == (5, 2) and not np.allclose(estimated, run.currents[:5], atol=0.01)
    assert (tmp_path / "s2_estimation.png").stat().st_size > 1000
    # the oracle on the same current is another configuration, its own record, no loop column
    assert cli.main([*flags, "--out", out]) == 0
    assert "loop" not in capsys.readouterr().out
    assert len(list((tmp_path / "runs").glob("s2_ipopt_*.npz"))) == 2
    assert cli.main([*flags, "--estimator", "ekff", "--out", out]) == 2
    line = _one_error_line(capsys)
    assert line.startswith("error: --estimator must be one of") and "did you mean 'ekf'?" in line


def test_follow_a_survey_with_ilos_prints_its_metrics(capsys):
    """``follow --solver ilos``: the REMUS survey, one table row; the path done (its end passed)."""
    assert cli.main(["follow", "--solver", "ilos", "--quiet"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any("path following, remus100, survey, 1.5 m/s, controller ilos" in line for line in lines)
    row = lines[-1].strip("| ").split(" | ")
    cross_rms, cross_max, depth_rms = (float(v) for v in row[:3])
    assert 0.0 < cross_rms < cross_max < 10.0 and depth_rms < 0.5
    assert row[-1] == "yes"


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--speed", "-1"], "--speed"),
        (["--solver", "newton"], "--solver"),
        (["--path", "nowhere.toml"], "--path"),
        (["--estimator", "kalman"], "--estimator"),
        (["--solver", "ilos", "--estimator", "ekf"], "--estimator"),
        (["--path", "s2"], "--duration"),  # the paper's references have no end
        (["--vehicle", "submarine"], "--vehicle"),
        (["--current-std", "fast"], "--current-std"),
        (["--current-std", "0.01,0.01"], "--current-std"),  # the REMUS's current has 3 axes
        (["--current-std", "0.01,0,0.01"], "--current-std"),
        (["--current-filter", "-1"], "--current-filter"),
        (["--current-filter", "nan"], "--current-filter"),
        (["--solver", "ilos", "--current-std", "0.05"], "--estimator"),  # unused without one
    ],
)
def test_follow_bad_input_is_one_line_and_exit_2(capsys, argv, named):
    assert cli.main(["follow", *argv]) == 2
    assert named in _one_error_line(capsys)


@pytest.mark.parametrize(
    ("argv", "current_std", "current_filter"),
    [
        ([], (0.01, 0.01, 1e-4), 20.0),  # the survey's horizontal current, low-passed 20 s
        (["--current-std", "0.02", "--current-filter", "0"], 0.02, 0.0),
        (["--current-std", "0.02,0.03,0.001"], (0.02, 0.03, 0.001), 20.0),
    ],
)
def test_follow_hands_the_estimator_its_current_options(
    monkeypatch, capsys, argv, current_std, current_filter
):
    """``follow --estimator ekf``: the EKF gets the survey options unless the flags say otherwise."""
    import uuv_ocp as uo

    told = {}

    def spy(problem, method=None, *, sensors, options=None, parameters=None):
        told["method"], told["options"] = method, options
        raise ValueError("spy: stop before the closed loop")

    monkeypatch.setattr(uo, "Estimator", spy)
    assert cli.main(["follow", "--estimator", "ekf", "--quiet", *argv]) == 2
    assert "spy: stop" in _one_error_line(capsys)
    assert told["method"] == "ekf"
    assert told["options"].current_std == current_std
    assert told["options"].current_filter == current_filter
