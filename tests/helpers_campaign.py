"""Shared by the campaign tests: a small campaign and a comparison of its records."""

from pathlib import Path

import numpy as np

from uuv_ocp.studies.campaign import CampaignConfig

# wall-clock arrays differ between two runs of the same trial; the checksum covers them
WALL_CLOCK = {"solve_times", "record_checksum"}
SMALL = {"reference": "s2", "solver": "sqp", "trials": 3, "duration": 2.0, "horizon": 8, "seed": 3}
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
