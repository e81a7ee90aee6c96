"""Curves: the function spaces of the flat outputs (polynomial, B-spline and piecewise bases)
and their quadrature.
"""
