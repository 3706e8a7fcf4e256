"""The bus's facts, shared by the master and the simulated drives: frame costs, error frames, subscriptions."""
