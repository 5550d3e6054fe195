"""General-purpose population optimisers (IGWO, GWO, SSA, PSO) behind one ``minimize``."""
