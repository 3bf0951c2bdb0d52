"""ManiSkill's own PegInsertionSide-v1, as mani-skill ships it, with what the library needs of it: the env adapter and
its predicates (`env`), its names (`spec`), the scene the planner may know (`scene`), the subtasks as waypoints
(`subtasks`), the description the library reads (`task`), and the scripted expert (`expert`)."""
