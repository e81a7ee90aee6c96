"""The paper's flat law written in plain Python (docs/development.md prints this module): a
controller with ``command`` for ``flatcli.track(..., controller=PaperLaw(...))``."""

import math


class PaperLaw:
    """Franch et al. (2003), eqs. 34-42: the flat outputs at the measured angles, v = y_d''
    + kv (y_d' - y') + kp (y_d - y), and the inputs (u1', u2) that make y'' = v."""

    def __init__(self, k, kp, kv):  # k: the model's coefficients (plan.model.coefficients)
        self.k, self.kp, self.kv = k, kp, kv

    def command(self, t, theta, u, flag):
        k, (th0, th1, th2), u1 = self.k, theta, u[0]
        c1, s1 = math.cos(th1), math.sin(th1)
        inv_a = 1.0 / (k.a0 + k.a1 * c1)                 # A = a0 + a1 cos th1
        g = (k.b0 + k.b1 * c1) * inv_a                   # g = B / A
        h = k.c0 * k.a1 * s1 * inv_a * inv_a             # h = c0 a1 sin th1 / A^2
        g1 = (g * k.a1 - k.b1) * s1 * inv_a              # dg/dth1
        h1 = k.c0 * k.a1 * (c1 + 2.0 * k.a1 * s1 * s1 * inv_a) * inv_a * inv_a
        y = (th1, th0 - k.c0 * th2 * inv_a)              # eq. 35
        y_dot = (u1, (g - h * th2) * u1)                 # eq. 36
        v = [flag[4 + j] + self.kv[j] * (flag[2 + j] - y_dot[j])
             + self.kp[j] * (flag[j] - y[j]) for j in (0, 1)]
        u2 = ((g - h * th2) * v[0] + (g1 - h1 * th2) * u1 * u1 - v[1]) / (h * u1)  # eq. 39
        return (v[0],), u2                               # u1' = v1, and th2' = u2
