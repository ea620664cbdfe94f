"""The planners: the OCP (transcriptions, Newton, IPOPT strategy), the gradient variant, the
baseline, the method registry, re-planning."""
