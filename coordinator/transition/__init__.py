"""T, the learned transition model, and the experience pool it is rebuilt from."""
