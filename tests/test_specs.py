"""Vehicle and reference specs (uuv_ocp.specs): files and names give the objects the API builds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uuv_ocp import Remus100, Vehicle, Vehicle6DOF
from uuv_ocp.reference.path import WAYPOINT_HOLD
from uuv_ocp.specs import (
    CSV_SPEED,
    CSV_TURN_RADIUS,
    VEHICLE_PRESETS,
    reference_from_spec,
    vehicle_from_spec,
)


def test_presets_by_name_are_the_classmethods():
    assert vehicle_from_spec("rexrov") == Vehicle.rexrov()
    assert vehicle_from_spec("rexrov-controller") == Vehicle.rexrov_controller_model()
    assert isinstance(vehicle_from_spec("bluerov2-heavy"), Vehicle6DOF)
    assert vehicle_from_spec("rexrov2").name == Vehicle6DOF.rexrov2().name
    assert vehicle_from_spec("remus100") == Remus100()
    thrusters = vehicle_from_spec("bluerov2-heavy-thrusters")
    assert thrusters.thrusters == Vehicle6DOF.bluerov2_heavy(thrusters=True).thrusters is not None
    assert vehicle_from_spec("rexrov2-thrusters").thrusters == Vehicle6DOF.rexrov2(thrusters=True).thrusters
    assert set(VEHICLE_PRESETS) == {
        "rexrov",
        "rexrov-controller",
        "bluerov2-heavy",
        "bluerov2-heavy-thrusters",
        "rexrov2",
        "rexrov2-thrusters",
        "remus100",
    }


def test_vehicle_file_overrides_a_preset_and_its_dynamics_follow(tmp_path):
    path = tmp_path / "light.toml"
    path.write_text(
        '[vehicle]\npreset = "rexrov"\nname = "light"\nmass = 1500.0\nadded_mass = [700, 1200, 200]\n'
    )
    vehicle = vehicle_from_spec(path)
    assert vehicle == dataclasses.replace(
        Vehicle.rexrov(), name="light", mass=1500.0, added_mass=(700.0, 1200.0, 200.0)
    )
    # surge acceleration from rest under 1000 N: tau / (m + X_u̇), written out independently
    rhs = np.asarray(vehicle.dynamics_function()(np.zeros(6), [1000.0, 0.0, 0.0], [0.0, 0.0])).ravel()
    assert rhs[3] == pytest.approx(1000.0 / (1500.0 + 700.0), rel=1e-12)


def test_vehicle_file_from_scratch(tmp_path):
    path = tmp_path / "own.toml"
    path.write_text(
        "[vehicle]\nmodel = 'planar'\nmass = 100.0\ninertia = 10.0\nadded_mass = [10, 20, 1]\n"
        "linear_damping = [5, 6, 1]\nquadratic_damping = [1, 2, 0.5]\nmax_thrust = [50, 50, 10]\n"
    )
    vehicle = vehicle_from_spec(str(path))
    assert vehicle.max_thrust == (50.0, 50.0, 10.0) and vehicle.mass == 100.0


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[vehicle]\npreset = 'rexrov'\nmas = 1.0\n", r"unknown vehicle field\(s\) \['mas'\]"),
        ("[vehicle]\npreset = 'nope'\n", "preset must be one of"),
        ("[vehicle]\nmass = 1.0\n", "give model"),
        ("[vehicle]\nmodel = 'planar'\nmass = 1.0\n", "missing"),
        ("[vehicle]\npreset = 'rexrov'\nmass = -1.0\n", "mass"),
        ("[vehicel]\npreset = 'rexrov'\n", r"expected one \[vehicle\] table"),
        ("[vehicle\n", "not valid TOML"),
    ],
)
def test_bad_vehicle_files_name_the_file_and_field(tmp_path, text, match):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=match) as raised:
        vehicle_from_spec(path)
    assert str(path) in str(raised.value)


def test_unknown_vehicle_name():
    with pytest.raises(ValueError, match="vehicle must be one of .* got 'bluerov'"):
        vehicle_from_spec("bluerov")


def test_waypoint_csv_is_the_straight_line_and_arc_path(tmp_path):
    path = tmp_path / "survey.csv"
    path.write_text("# x, y\n0, 0\n20, 0\n20, 10\n")
    reference = reference_from_spec(f"waypoints {path}")
    # length of two legs with a quarter-circle corner: 20 + 10 - 2 r + (pi/2) r
    length = 30.0 - 2.0 * CSV_TURN_RADIUS + 0.5 * np.pi * CSV_TURN_RADIUS
    # the mission, braking over the last turn radius (twice its time at speed), then the default
    # hold at the last waypoint
    braking = CSV_TURN_RADIUS / CSV_SPEED
    assert reference.t_end == pytest.approx(length / CSV_SPEED + braking + WAYPOINT_HOLD, rel=1e-12)
    start, end = reference.evaluate([0.0, reference.t_end])
    np.testing.assert_allclose(start[:2], [0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(end[:2], [20.0, 10.0], atol=1e-9)
    assert reference.name == "survey"


def test_waypoint_and_lawnmower_toml(tmp_path):
    path = tmp_path / "w.toml"
    path.write_text(
        "[reference]\npoints = [[0, 0, 2], [10, 0, 4]]\nspeed = 0.25\nturn_radius = 1.0\nhold = 5.0\n"
    )
    reference = reference_from_spec(["waypoints", str(path)])
    assert reference.spatial and reference.t_end == pytest.approx(40.0 + 1.0 / 0.25 + 5.0)  # braking 1 m
    np.testing.assert_allclose(reference.evaluate([20.0])[0][:3], [5.0, 0.0, 3.0], atol=1e-12)
    mower = tmp_path / "m.toml"
    mower.write_text("[reference]\nwidth = 20.0\nspacing = 4.0\nlanes = 3\nspeed = 0.5\n")
    survey = reference_from_spec(f"lawnmower {mower}")
    # lane ends (0,0) (20,0) (20,4) (0,4) (0,8) (20,8): legs 68 m, four 90° corners of radius 2 m,
    # each replacing 2 r of leg by a quarter circle of (pi/2) r
    assert survey.t_end == pytest.approx(
        (68.0 - 4 * 2 * 2.0 + 4 * 0.5 * np.pi * 2.0 + 2.0) / 0.5 + WAYPOINT_HOLD, rel=1e-9
    )


def test_paper_reference_lifted_for_a_six_dof_vehicle():
    planar = reference_from_spec("s2")
    spatial = reference_from_spec("s2", spatial=True, depth=7.0)
    assert not planar.spatial and spatial.spatial
    times = np.linspace(0.0, 20.0, 11)
    flat, deep = planar.evaluate(times), spatial.evaluate(times)
    np.testing.assert_allclose(deep[:, 0:2], flat[:, 0:2], atol=1e-12)  # x, y
    np.testing.assert_allclose(deep[:, 2], 7.0, atol=1e-12)  # z
    np.testing.assert_allclose(deep[:, 5], flat[:, 2], atol=1e-12)  # heading
    np.testing.assert_allclose(deep[:, 6:8], flat[:, 3:5], atol=1e-12)  # u, v
    np.testing.assert_allclose(deep[:, 8], 0.0, atol=1e-12)  # w: constant depth


def test_hold_spec():
    np.testing.assert_allclose(reference_from_spec("hold 1,2,0.5").evaluate([3.0])[0], [1, 2, 0.5, 0, 0, 0])


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("s11", "reference must be one of"),
        ("waypoints", "reference must be one of"),
        ("s1 s2", "reference must be one of"),
        ("waypoints /no/such.toml", "no such file"),
        ("hold a,b", "hold takes X,Y,PSI"),
        ("", "got nothing"),
    ],
)
def test_bad_reference_specs(spec, match):
    with pytest.raises(ValueError, match=match):
        reference_from_spec(spec)


def test_bad_reference_file_fields_name_the_file(tmp_path):
    path = tmp_path / "r.toml"
    path.write_text("[reference]\npoints = [[0, 0], [1, 0]]\nsped = 1.0\n")
    with pytest.raises(ValueError, match="bad fields for a waypoints reference") as raised:
        reference_from_spec(f"waypoints {path}")
    assert str(path) in str(raised.value)
    path.write_text("[reference]\nkind = 'spiral'\n")
    with pytest.raises(ValueError, match="kind must be one of"):
        reference_from_spec(str(path))


def test_example_spec_files_of_docs_cli_parse():
    """The files docs/cli.md shows and its commands use."""
    from pathlib import Path

    examples = Path(__file__).resolve().parents[1] / "examples"
    light = vehicle_from_spec(examples / "vehicles" / "light_rov.toml")
    assert light.name == "light-rov" and light.mass == 1200.0 and light.max_thrust[0] == 1500.0
    survey = reference_from_spec(["waypoints", str(examples / "paths" / "survey.csv")])
    np.testing.assert_allclose(survey.evaluate([survey.t_end])[0][:2], [0.0, 8.0], atol=1e-9)
    mower = reference_from_spec(["lawnmower", str(examples / "paths" / "lawnmower.toml")])
    assert mower.t_end > 5.0
