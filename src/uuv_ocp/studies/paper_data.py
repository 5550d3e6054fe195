"""The paper's numbers, transcribed once, so that no report types them by hand.

Source: W. Gan, T. Xia, Z. Chu, *A Prognosis Technique Based on Improved GWO-NMPC to Improve
the Trajectory Tracking Control System Reliability of Unmanned Underwater Vehicles*,
Electronics 2023, 12(4), 921 (https://doi.org/10.3390/electronics12040921), HTML text.
Every constant below cites the table or the sentence it comes from; the text of §4.2–4.3 is
quoted where a number comes from prose.  Units are the paper's: errors in m; its "covariance"
columns carry no unit in the tables (the prose of §4.2 calls them "mean square deviation ...
0.043 m").

Nothing here is computed: :mod:`uuv_ocp.studies.reproduce` compares these numbers with the
ones it measures.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

__all__ = [
    "BUDGETS",
    "REFERENCES",
    "STABLE_LEVEL",
    "TABLE1_MAX_ABS",
    "TABLE2_COVARIANCE",
    "TABLE3_COVARIANCE",
    "TABLE4_MAX_ABS",
    "TEXT_COVARIANCE_X",
    "TEXT_MAX_ABS_X",
    "TEXT_MAX_ABS_Y",
    "TIME_TO_BAND",
    "TRIALS",
    "TABLE_SOLVERS",
]


def _frozen(table: dict) -> Mapping:
    return MappingProxyType(table)


#: The ten references of Tables 1 and 2, in the tables' order.
REFERENCES = ("s1", "s2", "s3", "s4", "s5", "s6", "s7", "s8", "s9", "s10")

#: §4.2: "Each group of tests was independently conducted 50 times."
TRIALS = 50

#: Table 1, "Table of maximum absolute tracking error in each direction" (IGWO-NMPC):
#: (Max Error-X, Max Error-Y), "maximum absolute error of tracking error", averaged over the 50
#: trials (§4.2).
TABLE1_MAX_ABS: Mapping[str, tuple[float, float]] = _frozen(
    {
        "s1": (0.383, 0.348),
        "s2": (0.403, 0.384),
        "s3": (0.398, 0.221),
        "s4": (0.381, 0.378),
        "s5": (0.376, 0.269),
        "s6": (0.328, 0.367),
        "s7": (0.338, 0.379),
        "s8": (0.326, 0.362),
        "s9": (0.348, 0.383),
        "s10": (0.228, 0.394),
    }
)

#: Table 2, "Table of tracking error covariance in each direction" (IGWO-NMPC):
#: (Cov Error-X, Cov Error-Y), "average covariance of tracking error".
TABLE2_COVARIANCE: Mapping[str, tuple[float, float]] = _frozen(
    {
        "s1": (0.043, 0.129),
        "s2": (0.017, 0.213),
        "s3": (0.042, 0.193),
        "s4": (0.004, 0.144),
        "s5": (0.011, 0.235),
        "s6": (0.037, 0.135),
        "s7": (0.051, 0.198),
        "s8": (0.009, 0.228),
        "s9": (0.134, 0.139),
        "s10": (0.002, 0.147),
    }
)

#: The optimisers of Tables 3 and 4 (case II, s2: §4.3 "when the expected trajectory is
#: sinusoidal (case II)"), in the tables' order, as uuv_ocp solver names.
TABLE_SOLVERS = ("igwo", "gwo", "ssa", "sqp")

#: Table 3, "Table of tracking error covariance in each direction of algorithms" (s2):
#: (Cov Error-X, Cov Error-Y).
TABLE3_COVARIANCE: Mapping[str, tuple[float, float]] = _frozen(
    {
        "igwo": (0.0173, 0.213),
        "gwo": (0.0284, 0.224),
        "ssa": (0.0534, 0.249),
        "sqp": (0.0398, 0.255),
    }
)

#: Table 4, "Table of maximum absolute tracking error in each direction of algorithms" (s2):
#: (Max Error-X, Max Error-Y).
TABLE4_MAX_ABS: Mapping[str, tuple[float, float]] = _frozen(
    {
        "igwo": (0.343, 0.384),
        "gwo": (0.472, 0.783),
        "ssa": (0.515, 0.467),
        "sqp": (0.524, 0.778),
    }
)

#: §4.3 prose: "The average covariance of tracking error in x-direction is 0.0173 m, whereas
#: the average covariance of tracking error in the direction of SQP, GWO and SSA are 0.0398 m,
#: 0.0184 m and 0.0534 m, respectively."
TEXT_COVARIANCE_X: Mapping[str, float] = _frozen(
    {"igwo": 0.0173, "sqp": 0.0398, "gwo": 0.0184, "ssa": 0.0534}
)

#: §4.3 prose: "the maximum absolute tracking error of the IGWO in the x direction is much
#: smaller, only 0.343 m, whereas the maximum absolute tracking error of GWO, SQP and SSA in this
#: direction is 0.472 m, 0.515 m and 0.524 m, respectively."
TEXT_MAX_ABS_X: Mapping[str, float] = _frozen({"igwo": 0.343, "gwo": 0.472, "sqp": 0.515, "ssa": 0.524})

#: §4.3 prose: "The maximum absolute tracking error of the IGWO in the y direction is also much
#: smaller, only 0.384 m, whereas the absolute value of the maximum tracking error of SQP and GWO
#: in this direction is 0.778 m and 0.783 m."
TEXT_MAX_ABS_Y: Mapping[str, float] = _frozen({"igwo": 0.384, "sqp": 0.778, "gwo": 0.783})

#: §4.3 prose: "the tracking control of the IGWO algorithm in the x-direction can reach a stable
#: error range faster, which only takes about 1 s on average, whereas the SQP algorithm takes
#: about 2 s, and the GWO algorithm takes about 2.5 s" (s (seconds), case II, s2).
TIME_TO_BAND: Mapping[str, float] = _frozen({"igwo": 1.0, "sqp": 2.0, "gwo": 2.5})

#: §4.2 prose (IGWO): "when the average optimization time in case I reaches about 2 s, the
#: tracking error ... in the x-direction is basically stable at about 0.25 m.  When the average
#: optimization time in case II reaches about 1 s, the tracking error ... in the x-direction is
#: basically stable at about 0.3 m": reference -> (time s, stable |e_x| level m).
STABLE_LEVEL: Mapping[str, tuple[float, float]] = _frozen({"s1": (2.0, 0.25), "s2": (1.0, 0.3)})

#: §4.3: "the IGWO-NMPC only needs to set the population number and maximum iteration number
#: to 20 and 30 ... GWO-NMPC ... 30 and 40 ... SSA-NMPC ... 50 and 80": (population, iterations).
BUDGETS: Mapping[str, tuple[int, int]] = _frozen({"igwo": (20, 30), "gwo": (30, 40), "ssa": (50, 80)})
