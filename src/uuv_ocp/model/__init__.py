"""Vehicle models: the 3-DOF planar :class:`Vehicle` and the 6-DOF :class:`Vehicle6DOF`."""
