"""Outputs: the solution file, safe writes, trajectory export, comparison and its figures, the plot
styles."""
