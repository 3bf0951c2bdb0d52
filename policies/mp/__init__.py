"""Motion planning (paper: MP): OMPL RRT-Connect plans, time-parameterised, run open loop."""
