"""Vehicle models: the 3-DOF planar :class:`Vehicle` and the 6-DOF :class:`Vehicle6DOF`.

A model provides ``state_dim``, ``control_dim``, ``current_dim``, its symmetric control and
rate bounds, and a continuous-time right-hand side on CasADi symbols; presets cite sources.
"""

from uuv_ocp.model.fossen6dof import Vehicle6DOF
from uuv_ocp.model.planar import Vehicle
from uuv_ocp.model.thrusters import ThrusterConfiguration

__all__ = ["ThrusterConfiguration", "Vehicle", "Vehicle6DOF"]
