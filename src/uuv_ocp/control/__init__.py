"""Closed loop: the receding-horizon controller, the plant simulation, disturbances, metrics."""
