"""ManiSkill's own PegInsertionSide-v1, as mani-skill ships it, with what the library needs of it: the env and its
predicates (`env`), the scripted expert (`expert`)."""
