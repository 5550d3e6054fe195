"""Vehicle models: the protocol, :class:`Vehicle` (3-DOF), :class:`Vehicle6DOF`, :class:`Remus100`.

:class:`Remus100` is the REMUS 100 torpedo AUV, steered by fins.  A model provides a
:class:`VehicleLayout` (state and control names and units; positions, angles,
heading, velocity block; current size; kind of reference), symmetric control and rate bounds,
and its continuous-time dynamics as a CasADi Function (:mod:`uuv_ocp.model.base`); presets cite
sources.
"""

from uuv_ocp.model.base import VehicleLayout, VehicleModel
from uuv_ocp.model.fossen6dof import Vehicle6DOF
from uuv_ocp.model.planar import Vehicle
from uuv_ocp.model.remus100 import Remus100
from uuv_ocp.model.thrusters import ThrusterConfiguration

__all__ = [
    "Remus100",
    "ThrusterConfiguration",
    "Vehicle",
    "Vehicle6DOF",
    "VehicleLayout",
    "VehicleModel",
]
