"""ROS 2 over DDS without ROS: `surestep serve` (the re-planning node) and `surestep sim-robot` (a
simulated PSM and tracker), on Cyclone DDS (`pip install 'surestep_ocp[ros]'`; docs/serve.md).

Nothing here is imported by `import surestep_ocp`: the CLI loads these modules only for those two
commands, and only they need `cyclonedds`.
"""
