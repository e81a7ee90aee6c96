"""Plants: what the robot does with a controller's joint-rate commands, knowing nothing of the
controller (``kinematic``, ``dynamic``; the paper's N = 2 closed form of both stays in
``loop.paperloop``, the paper model's speed).
"""
