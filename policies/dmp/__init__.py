"""Dynamic movement primitives (paper: DMP), fitted to the motion planner's trajectories."""
