"""The problem: what a problem is (spec), reading it (load, parse, schema, paths, ipopt_options),
and the set-up that resolves it (setup: robot, camera, start, goal)."""
