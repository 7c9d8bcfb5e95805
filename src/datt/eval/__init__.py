"""Evaluation: seeded reference banks, rollouts, metrics, plots."""
