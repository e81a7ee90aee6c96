"""Plans: point-to-point, exact, rest-to-rest and task plans, with their proofs (clearance,
interval bounds) and inverse kinematics.
"""
