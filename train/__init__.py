"""Training with Brax PPO (arrives with the training issue)."""
