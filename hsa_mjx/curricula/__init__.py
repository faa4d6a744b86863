"""Curricula: the goal-distance and terrain-level state machines, pure functions of their state."""
