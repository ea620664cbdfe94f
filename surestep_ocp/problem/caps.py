"""The caps on the values a problem (or evaluation) file may hold (problems/README.md,
"Limits"): every section reader checks its numbers against them.
"""

# Limits of what a problem (or evaluation) file may hold (problems/README.md, "Limits").
MAX_HORIZON = 200  # T (a solve's time and memory grow with T; problems/README.md "Limits")
MAX_POSITION = 100.0  # [m] any position (poses, points)
MAX_ANGLE = 1000.0  # [rad] any angle, axis-angle or joint value
MAX_FOCAL = 1e6  # [px]
MAX_IMAGE = 100_000  # [px] image width and height
MAX_FRAMES_PER_STEP = 10_000
