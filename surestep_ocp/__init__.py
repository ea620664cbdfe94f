"""SURESTEP belief-space trajectory optimisation."""
__version__ = "0.1.0"
