"""Studies built on the closed loop: solver comparisons and Monte Carlo campaigns."""
