"""Evaluation: rollouts, the simulated tracker, metrics, the Monte-Carlo evaluation, Table II,
sweeps."""
