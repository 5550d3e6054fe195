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
