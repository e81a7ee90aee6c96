"""Controllers: the feedback laws (the flat linearising law, the as-built LQR).
"""
