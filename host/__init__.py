"""SNAN agent, grid environments, experiments and hardware-in-the-loop runs."""
