"""The random-walk MDP of the paper's first experiment: the env (`env`), its five controllers (`controllers`), and
their exact or noisy tabular dynamics and goal score (`models`)."""
