"""Recording ManiSkill rollouts into LeRobot datasets, the recipes of the project's datasets, and their checks."""
