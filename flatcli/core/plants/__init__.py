"""Plants: what the robot does with a controller's joint-rate commands, knowing nothing of the
controller (``kinematic``, ``dynamic``; ``paper``: both in the paper's N = 2 closed form, the
paper model's speed).
"""
