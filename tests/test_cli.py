"""Command line and the resumable reproduction job."""

from uuv_ocp import cli
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

    rhs = vehicle.dynamics_function()
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
    assert "bluerov2" in capsys.readouterr().out.lower()
    (saved,) = (tmp_path / "runs").glob("s2*.npz")
    run = ClosedLoopResult.load(str(saved))
    assert run.states.shape == (6, 12)
    np.testing.assert_allclose(run.reference[:, 2], DEFAULT_DEPTH, atol=1e-12)


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
    from uuv_ocp.solvers.options import declared_options

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
