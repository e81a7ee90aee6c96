"""The closed loop: integrators, the compiled kernels, metrics, the loops of each model and
plant, the scipy reference, and ``simulate``.
"""
