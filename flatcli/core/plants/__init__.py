"""Plants: what the robot does with a controller's commands (kinematic, dynamic). Empty for
now: the loops' plants still live in ``flatcli.core.loop``.
"""
