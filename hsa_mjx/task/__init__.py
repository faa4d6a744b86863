"""Task layer: the single env (reset/step) and its control, goals, observation, reward and termination."""
