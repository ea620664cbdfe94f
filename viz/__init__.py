"""Meshcat visualisation (optional dependency: meshcat)."""
