"""Figures of uuv_ocp.plotting: labelled axes with units, legends, log scales, marked steps, file formats.

The runs are made by hand (no solver runs), so every marked kind of step is present where the
test puts it and the figures are checked against known data.
"""

from __future__ import annotations

import dataclasses
import gc
import re
import warnings

import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp import plotting
from uuv_ocp.model import Vehicle6DOF
from uuv_ocp.studies.compare import ComparisonRow

UNIT = re.compile(r"\((m|s|N|N·m|rad|m/s|rad/s|ms|[^)]+)\)$")


def fake_run(solver="fatrop", nx=6, nu=3, steps=40, scale=1.0, seed=0, **flags):
    """Make a closed-loop result on a sine reference whose error decays from `scale` m to ~1e-7 m."""
    rng = np.random.default_rng(seed)
    t = 0.1 * np.arange(steps + 1)
    reference = np.zeros((steps + 1, nx))
    reference[:, 0] = 0.5 * t
    reference[:, 1] = 2 * np.sin(0.5 * t)
    states = reference.copy()
    decay = scale * np.exp(-3.0 * t)[:, None]
    states[:, :2] += decay * (1 + 0.1 * rng.standard_normal((steps + 1, 2)))
    states[0] = reference[0]  # starts on the path: the error is exactly 0 there
    base = dict(
        t=t,
        states=states,
        controls=rng.uniform(-1000, 1000, (steps, nu)),
        reference=reference,
        solve_times=np.full(steps, 0.003),
        iterations=np.full(steps, 4),
        fallback_steps=np.zeros(steps, dtype=bool),
        relaxed_steps=np.zeros(steps, dtype=bool),
        currents=np.zeros((steps + 1, 2)),
        statuses=("Solve_Succeeded",) * steps,
        solver=solver,
    )
    for name, indices in flags.items():
        mask = np.zeros(steps, dtype=bool)
        mask[list(indices)] = True
        base[name] = mask
    return uo.ClosedLoopResult(**base)


def legend_texts(axis):
    legend = axis.get_legend()
    assert legend is not None, axis.get_title()
    return [text.get_text() for text in legend.get_texts()]


def visible_axes(figure):
    return [axis for axis in figure.axes if axis.get_visible()]


def assert_units(label):
    assert UNIT.search(label), f"axis label without a unit: {label!r}"


@pytest.fixture
def runs():
    return [
        fake_run(relaxed_steps=range(0, 5)),
        fake_run(seed=1, fallback_steps=[10], deadline_steps=[12, 13]),
        fake_run(seed=2),
    ]


LABELS = ["fatrop, still water", "fatrop, 0.3 m/s current", "fatrop, mismatch"]


def test_default_labels_number_repeated_solvers(runs):
    assert plotting.run_labels(runs) == ["fatrop #1", "fatrop #2", "fatrop #3"]
    assert plotting.run_labels([runs[0], fake_run("ipopt")]) == ["fatrop", "ipopt"]
    with pytest.raises(ValueError, match="one string per run"):
        plotting.run_labels(runs, ["a", "b"])
    with pytest.raises(ValueError, match="sequence of strings"):
        plotting.run_labels(runs, "abc")


def test_xoy_figure_has_reference_obstacles_labels_marks_and_plans(runs):
    obstacles = [uo.Obstacle.circle((2.0, 1.0), 0.3, margin=0.2), uo.Obstacle.circle((3.0, 0.0), 0.2)]
    plan = np.column_stack([np.linspace(0, 1, 11), np.linspace(0, 1, 11)])
    figure = plotting.xoy_figure(runs, labels=LABELS, obstacles=obstacles, plans=[plan], unreachable_from=3.0)
    (axis,) = figure.axes
    assert axis.get_xlabel() == "x (m)" and axis.get_ylabel() == "y (m)"
    texts = legend_texts(axis)
    for expected in [
        *LABELS,
        "reference",
        "keep-out zone",
        "safety margin",
        "predicted horizon",
        "path beyond the vehicle's reach",
        "soft terminal (relaxed)",
        "failed (fallback applied)",
        "deadline missed",
    ]:
        assert expected in texts, expected
    assert "fatrop" not in texts  # the user's labels replace the solver name
    assert len(axis.patches) == 3  # two zones, one margin ring
    # the failed step is drawn where the second run was at step 10
    markers = [line for line in axis.lines if line.get_marker() == "X"]
    assert len(markers) == 1
    np.testing.assert_allclose(markers[0].get_xydata(), runs[1].states[[10], :2])


def test_obstacle_figure_is_the_path_figure_with_zones(runs):
    figure = plotting.obstacle_figure(runs[:2], [uo.Obstacle.circle((2.0, 1.0), 0.3)], labels=LABELS[:2])
    texts = legend_texts(figure.axes[0])
    assert LABELS[0] in texts and "keep-out zone" in texts
    assert figure.axes[0].get_title() == "paths among obstacles"


def test_error_figure_is_logarithmic_in_abs_error_with_units(runs):
    figure = plotting.error_figure(runs, labels=LABELS)
    axes = figure.axes
    assert [axis.get_ylabel() for axis in axes] == ["|e_x| (m)", "|e_y| (m)", "|e_ψ| (rad)"]
    assert all(axis.get_yscale() == "log" for axis in axes)
    assert axes[-1].get_xlabel() == "t (s)"
    texts = legend_texts(axes[0])
    assert all(label in texts for label in LABELS)
    assert {"soft terminal (relaxed)", "failed (fallback applied)", "deadline missed"} <= set(texts)
    # the settled error (~1e-7 m) is on the axis, not squashed against zero
    line = next(line for line in axes[0].lines if line.get_label() == LABELS[0])
    values = line.get_ydata()
    assert np.isnan(values[0])  # exact zero at the start: left out of a log axis
    expected = np.abs(runs[0].errors[1:, 0])
    np.testing.assert_allclose(values[1:], np.maximum(expected, plotting.ERROR_FLOOR))
    low, _ = axes[0].get_ylim()
    assert low < np.nanmin(values) < 1e-5


def test_error_figure_linear_signed_and_6dof_depth():
    run = fake_run(nx=12, nu=6)
    figure = plotting.error_figure(run, log=False, heading=False)
    labels = [axis.get_ylabel() for axis in figure.axes]
    assert labels == ["e_x (m)", "e_y (m)", "e_z (m)"]
    assert all(axis.get_yscale() == "linear" for axis in figure.axes)
    ocp_run = dataclasses.replace(run, reference=np.full_like(run.reference, np.nan))
    with pytest.raises(ValueError, match="no reference"):
        plotting.error_figure(ocp_run)


def test_thrust_figure_units_bounds_and_labels(runs):
    vehicle = uo.Vehicle.rexrov()
    figure = plotting.thrust_figure(runs, labels=LABELS, vehicle=vehicle)
    axes = visible_axes(figure)
    assert [axis.get_ylabel() for axis in axes] == ["F_u (N)", "F_v (N)", "F_r (N·m)"]
    assert axes[-1].get_xlabel() == "t (s)"
    texts = legend_texts(axes[0])
    assert all(label in texts for label in LABELS) and "bound" in texts
    assert "failed (fallback applied)" in texts
    bounds = sorted({line.get_ydata()[0] for line in axes[0].lines if line.get_linestyle() == ":"})
    assert bounds == [-2000.0, 2000.0]


def test_thrust_figure_6dof_thrusters_and_generic_controls():
    boat = Vehicle6DOF.bluerov2_heavy(thrusters=True)
    run = fake_run(nx=12, nu=boat.control_dim)
    axes = visible_axes(plotting.thrust_figure(run, vehicle=boat))
    assert len(axes) == 8 and all(axis.get_ylabel().endswith("(N)") for axis in axes)
    assert {axis.get_xlabel() for axis in axes[-2:]} == {"t (s)"}
    generic = fake_run(nu=2)
    with pytest.raises(ValueError, match="units"):
        plotting.thrust_figure(generic)
    axes = visible_axes(
        plotting.thrust_figure(generic, names=["a_x", "a_y"], units=["m/s²"] * 2, bounds=(-1, 1))
    )
    assert [axis.get_ylabel() for axis in axes] == ["a_x (m/s²)", "a_y (m/s²)"]


@pytest.mark.parametrize(
    ("nx", "expected"),
    [
        (6, ["ψ (rad)", "u (m/s)", "v (m/s)", "r (rad/s)"]),
        (12, ["ψ (rad)", "z (m)", "u (m/s)", "v (m/s)", "w (m/s)", "r (rad/s)"]),
    ],
)
def test_state_figure_heading_and_velocities(nx, expected):
    runs = [fake_run(nx=nx, relaxed_steps=[1]), fake_run(nx=nx, seed=3)]
    figure = plotting.state_figure(runs, labels=["a", "b"], unreachable_from=2.0)
    axes = visible_axes(figure)
    assert [axis.get_ylabel() for axis in axes] == expected
    assert {axis.get_xlabel() for axis in axes[-2:]} == {"t (s)"}
    texts = legend_texts(axes[0])
    assert {"a", "b", "reference", "soft terminal (relaxed)", "path beyond the vehicle's reach"} <= set(texts)
    with pytest.raises(ValueError, match="vehicle state"):
        plotting.state_figure(fake_run(nx=4))


def test_figures_and_metrics_find_states_by_role_not_by_name_or_place():
    """A vehicle that names and orders its states its own way: the recorded roles place them."""
    standard = fake_run(nx=6)
    order = [3, 2, 0, 5, 1, 4]  # surge, heading, north, yaw rate, east, sway
    renamed = dataclasses.replace(
        standard,
        states=standard.states[:, order],
        reference=standard.reference[:, order],
        state_names=("surge", "yaw", "north", "yaw_rate", "east", "sway"),
        state_units=("m/s", "rad", "m", "rad/s", "m", "m/s"),
        state_roles=("velocity", "psi", "x", "velocity", "y", "velocity"),
    )
    np.testing.assert_array_equal(renamed.errors, standard.errors)
    renamed_metrics, standard_metrics = renamed.metrics(settle_time=1.0), standard.metrics(settle_time=1.0)
    assert renamed_metrics.keys() == standard_metrics.keys()
    assert all(
        renamed_metrics[key] == pytest.approx(standard_metrics[key], nan_ok=True) for key in renamed_metrics
    )
    # the standard run is read by its width (no names, no roles): the same panels, the same lines
    for renamed_axis, standard_axis in zip(
        visible_axes(plotting.error_figure(renamed, heading=True)),
        visible_axes(plotting.error_figure(standard, heading=True)),
        strict=True,
    ):
        assert renamed_axis.get_ylabel() == standard_axis.get_ylabel()
        np.testing.assert_array_equal(
            renamed_axis.get_lines()[0].get_ydata(), standard_axis.get_lines()[0].get_ydata()
        )
    states = plotting.state_figure(renamed)
    assert [axis.get_ylabel() for axis in visible_axes(states)] == [
        "ψ (rad)",
        "surge (m/s)",
        "yaw_rate (rad/s)",
        "sway (m/s)",
    ]
    for axis, column in zip(visible_axes(states), (1, 0, 3, 5), strict=True):
        np.testing.assert_array_equal(axis.get_lines()[1].get_ydata(), renamed.states[:, column])


def comparison_rows():
    def row(solver, cost, violation, time, feasible, rank):
        return ComparisonRow(solver, cost, violation, time, 10, True, cost / 11.5, None, {}, feasible, rank)

    return [
        row("igwo", 1874.6, 0.15, 0.012, False, 4),
        row("ipopt", 11.5, 0.0, 0.0064, True, 1),
        row("sqp", 11.5, 3e-12, 0.0014, True, 2),
        row("fatrop", 11.5, 1e-9, 0.0037, True, 3),
    ]


def test_comparison_figure_cost_violation_time():
    figure = plotting.comparison_figure(comparison_rows())
    cost, violation, time = figure.axes
    assert cost.get_xlabel() == "judged cost (objective units)"
    assert violation.get_xlabel() == "largest violation (units of its kind)"
    assert time.get_xlabel() == "time per solve (ms)"
    assert all(axis.get_xscale() == "log" for axis in figure.axes)
    assert cost.get_ylabel() == "solver (best first)"
    # rank order, best at the top
    ticks = sorted(zip(cost.get_yticks(), [t.get_text() for t in cost.get_yticklabels()], strict=True))
    assert [name for _, name in ticks][::-1] == ["ipopt", "sqp", "fatrop", "igwo"]
    texts = legend_texts(violation)
    assert texts == ["feasible", "infeasible (ranked after)", "tolerance 1e-06"]
    widths = [patch.get_x() + patch.get_width() for patch in time.patches]
    np.testing.assert_allclose(sorted(widths), sorted([12.0, 6.4, 1.4, 3.7]))
    # zero violation drawn at the floor of the log axis
    ends = [patch.get_x() + patch.get_width() for patch in violation.patches]
    assert min(ends) == pytest.approx(plotting.VIOLATION_FLOOR)


def test_comparison_figure_linear_cost_when_not_positive():
    rows = comparison_rows()
    rows[1] = dataclasses.replace(rows[1], cost=-3.0)
    assert plotting.comparison_figure(rows).axes[0].get_xscale() == "linear"


@pytest.mark.parametrize("suffix", [".png", ".svg", ".pdf"])
def test_save_figure_format_by_suffix(tmp_path, runs, suffix):
    path = plotting.save_figure(plotting.error_figure(runs), tmp_path / "deep" / f"errors{suffix}")
    data = path.read_bytes()
    signature = {".png": b"\x89PNG", ".svg": b"<?xml", ".pdf": b"%PDF"}[suffix]
    assert data.startswith(signature) and len(data) > 1000
    if suffix == ".svg":  # vector: text as glyph outlines, each after a comment with its string
        assert b"<svg" in data and b"<!-- |e_x| (m) -->" in data


def test_save_figure_rejects_unknown_suffix(tmp_path, runs):
    with pytest.raises(ValueError, match=r"\.png, \.svg, \.pdf"):
        plotting.save_figure(plotting.xoy_figure(runs), tmp_path / "figure.jpeg")
    with pytest.raises(ValueError, match="must end in"):
        plotting.save_figure(plotting.xoy_figure(runs), tmp_path / "figure")


def test_save_tracking_figures_writes_four_pdfs(tmp_path, runs):
    paths = plotting.save_tracking_figures(
        runs, tmp_path, prefix="s2_", suffix=".pdf", labels=LABELS, vehicle=uo.Vehicle.rexrov()
    )
    assert set(paths) == {"xoy", "errors", "thrust", "states"}
    for name, path in paths.items():
        assert path.name == f"s2_{name}.pdf" and path.read_bytes().startswith(b"%PDF")


def test_animation_gif(tmp_path):
    pytest.importorskip("PIL")
    moving = uo.Obstacle.moving(lambda t: (1.0 + 0.1 * t, 0.5), 0.2, margin=0.1)
    run = fake_run(steps=20)
    animation = plotting.closed_loop_animation(
        [run, fake_run(seed=4, steps=20)], obstacles=[moving], stride=5
    )
    path = plotting.save_animation(animation, tmp_path / "loop.gif", fps=5)
    data = path.read_bytes()
    assert data.startswith(b"GIF8")
    from PIL import Image

    with Image.open(path) as image:
        assert image.n_frames == 5  # samples 0, 5, 10, 15, 20
    # the moving obstacle moved with the frames (last frame drawn: t = 2.0 s)
    body = animation._fig.axes[0].patches[0]
    np.testing.assert_allclose(body.get_center(), moving.centre_at([run.t[-1]])[0])
    with pytest.raises(ValueError, match=r"\.gif or \.mp4"):
        plotting.save_animation(animation, tmp_path / "loop.avi")
    with pytest.raises(ValueError, match="stride"):
        plotting.closed_loop_animation(run, stride=0)


def test_animation_writer_missing_is_a_clear_error(tmp_path, monkeypatch):
    import importlib.util

    from matplotlib import animation as mpl_animation

    animation = plotting.closed_loop_animation(fake_run(steps=4))
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None if name == "PIL" else real(name))
    with pytest.raises(plotting.AnimationWriterUnavailable, match="needs pillow"):
        plotting.save_animation(animation, tmp_path / "loop.gif")
    monkeypatch.setattr(mpl_animation.writers, "is_available", lambda name: False)
    with pytest.raises(plotting.AnimationWriterUnavailable, match="needs ffmpeg"):
        plotting.save_animation(animation, tmp_path / "loop.mp4")
    with warnings.catch_warnings():  # matplotlib warns when an animation is deleted unrendered
        warnings.simplefilter("ignore", UserWarning)
        del animation
        gc.collect()


def test_figures_from_a_real_closed_loop(tmp_path):
    """A short NMPC run (from rest: the first steps are relaxed) through every tracking figure."""
    reference = uo.Reference.paper("s2")
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), reference, horizon=10, dt=0.1)
    run = uo.simulate(uo.NMPC(problem, "sqp"), reference.initial_state(0.0), 1.0)
    assert run.relaxed_steps.any()
    paths = plotting.save_tracking_figures(run, tmp_path, suffix=".svg", labels=["sqp, N = 10"])
    for path in paths.values():
        text = path.read_text()
        assert text.startswith("<?xml") and "sqp, N = 10" in text
