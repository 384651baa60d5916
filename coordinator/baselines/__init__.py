"""The baselines' own learning: TMP-RL's grounding bandit and the Gymnasium agents."""
