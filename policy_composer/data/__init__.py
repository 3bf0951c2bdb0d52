"""Dataset I/O: LeRobot datasets of ManiSkill rollouts (features, recorder, journal), recipes, frame loading."""
