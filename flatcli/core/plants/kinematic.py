"""The kinematic plant of an N-link chain: each joint turns at its commanded rate, clipped to
the rate limit, and the base turns as the plant's own angular momentum makes it. It takes
joint-rate commands and knows nothing of the controller that made them.

    th_j' = sat(r_j) (j = 1..N),   th0' = (H0 - sum_j h_j th_j') / h_0

with h the plant's momentum weights (``chain.momentum_weights_given``: its own K and
inertias, any d_N) and sat the clip to +-rate_limit (infinite: none).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.robots.chain import momentum_weights_given

Array = NDArray[np.float64]


@jitable
def kinematic_rates(K: Array, inertia: Array, h0: float, rate_limit: float, cs: Array,
                    sn: Array, h: Array, r: Array, out: Array) -> None:
    """The kinematic plant's rates th0'..th_N' [rad/s] into ``out[:N + 1]``.

    K (N + 1, N + 1), inertia (N + 1,): the plant's; h0 its angular momentum [kg m^2/s];
    cs, sn (N + 1,): its links' trigonometry (``chain.link_trig``, its last link turned
    where its centre of mass is across it); h (N + 1,) scratch (left holding its momentum
    weights); r (>= N,) the joint-rate commands [rad/s] of joints 1..N.
    """
    momentum_weights_given(K, inertia, cs, sn, h)
    base = h0
    for j in range(1, cs.shape[0]):
        rate = min(max(r[j - 1], -rate_limit), rate_limit)
        out[j] = rate
        base -= h[j] * rate
    out[0] = base / h[0]
