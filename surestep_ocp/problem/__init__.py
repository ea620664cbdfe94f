"""The problem: the YAML schema and loader, and the set-up that resolves it (robot, camera, start, goal)."""
