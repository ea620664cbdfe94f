"""What users call, each a Setup in and a Solution out: the baseline, the paper's gradient
variant, the OCP solved by its strategy, planning to a confidence, the Planner that re-plans in a
loop, re-planning after camera moves, and the registry that names them."""
