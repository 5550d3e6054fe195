"""References over time: symbolic paths, the paper's s1..s10, waypoints and station keeping."""
