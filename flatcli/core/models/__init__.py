"""Models: what a planner and a controller believe of a robot (the flat-model interface, the
paper's closed form, the N-link chain's outputs).
"""
