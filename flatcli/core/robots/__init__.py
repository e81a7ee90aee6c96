"""Robots: what a robot is (its parameters, the chain's lever arms and momentum, dynamics,
kinematics, designs and counterweights).
"""
