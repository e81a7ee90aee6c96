"""A small dense convex QP solver for compiled loops: the dual active-set method of Goldfarb
and Idnani.

    minimise  1/2 x' G x + g' x    subject to   C[k] x = lo[k]              (k < meq)
                                                lo[k] <= C[k] x (+ s) ,  C[k] x (- s) <= hi[k]
                                                                        (meq <= k < m)

with G symmetric positive definite (n x n), C (m, n) the constraints' rows, either bound of an
inequality possibly infinite, and s = x[n - 1] added to both sides of a *soft* row (``soft``:
the caller's slack variable, which a row of its own keeps >= 0). Row k reads only its first
``width[k]`` columns (the rows of a predictive controller's later samples are longer than
its earlier ones'), so the cost of a pass over the rows follows their lengths.

The method (D. Goldfarb, A. Idnani, "A numerically stable dual method for solving strictly
convex quadratic programs", Math. Programming 27, 1983; the same algorithm as the Fortran of
the ``quadprog`` package, which the tests use as the referee) starts from the unconstrained
minimiser x = -G^-1 g and adds violated constraints one at a time, dropping an active one
where its multiplier would turn negative, so that every iterate is optimal for the
constraints active so far: the dual objective rises monotonically and the method ends in
finitely many steps. It works with J = L^-T (G = L L', L lower triangular: J J' = G^-1),
rotated by Givens rotations as constraints enter and leave, and R upper triangular with
J' N_A = [R; 0] for the normals N_A of the active constraints. J is kept transposed (its
columns as rows): the rotations, most of an iteration's work, then run along contiguous
memory (the MPC's step at horizon 20, 41 variables, 4 rad/s: 57 us at its first sample and
22 us on average, against 67 and 26 us with J's columns strided, alternately at load 3,
2026-12-05).

Model predictive control solves one such problem per sample with the same G (``mpc``):
``factor`` computes J once, and ``solve`` copies it. ``solve`` allocates nothing (every
buffer is the caller's: ``Work``), so it runs inside kernels compiled without numba's
runtime (``_jit.kernel``) as well as from Python on numpy arrays.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable

Array = NDArray[np.float64]

#: A normal whose part outside the active normals' span (|d[q:]|^2) is below this times its
#: size (|d|^2) counts as a combination of them: no primal step along it.
DEPENDENT = 1e-14

#: ``solve``'s statuses: the optimum found; the constraints cannot all be met (the last
#: constraint tried is inconsistent with the active ones); the iteration budget spent.
OPTIMAL = 0
INFEASIBLE = 1
MAX_ITERATIONS = 2

#: A constraint counts as met when it is violated by at most this times the norm of its row
#: (the scale of its bounds), and an equality as met within it too.
TOLERANCE = 1e-10


class Work(NamedTuple):
    """A solver's buffers for n variables and up to m constraints (``work``).

    J (n, n): the factor J' (row j is J's column j), R (n, n) (module docstring); d, z,
    r (n,): the step's
    directions; u (n,): the active constraints' multipliers; active (n,): their rows, as
    2 k for the lower bound of row k (and equalities) and 2 k + 1 for its upper bound;
    norms (m,): the rows' Euclidean norms.
    """

    J: Array
    R: Array
    d: Array
    z: Array
    r: Array
    u: Array
    active: NDArray[np.int64]
    norms: Array


def work(n: int, m: int) -> Work:
    """Fresh buffers for ``solve`` with n variables and up to m constraints."""
    return Work(np.zeros((n, n)), np.zeros((n, n)), np.zeros(n), np.zeros(n), np.zeros(n),
                np.zeros(n), np.zeros(n, dtype=np.int64), np.zeros(max(m, 1)))


def factor(G: Array) -> Array:
    """J' = L^-1 (n, n) of a symmetric positive definite G = L L' (``solve``'s first factor,
    J = L^-T, transposed as ``Work.J`` keeps it); numpy's Cholesky (LinAlgError if G is not
    positive definite)."""
    L = np.linalg.cholesky(np.asarray(G, dtype=float))
    return np.ascontiguousarray(np.linalg.inv(L))


@jitable
def _rotate_columns(J: Array, a: int, b: int, c: float, s: float) -> None:
    """Columns a, b of J replaced by c J[:, a] + s J[:, b] and -s J[:, a] + c J[:, b]: rows
    a, b of the transposed J that ``Work.J`` holds."""
    ra = J[a]
    rb = J[b]
    for i in range(J.shape[1]):
        ja = ra[i]
        jb = rb[i]
        ra[i] = c * ja + s * jb
        rb[i] = -s * ja + c * jb


@jitable
def _add(w: Work, q: int, n: int) -> bool:
    """Make the step direction's normal (d = J' n_p) the (q + 1)-th active one: rotate
    d[q:] onto d[q] (and J's columns with it) and append d[:q + 1] to R as column q.
    False if the normal is (numerically) a combination of the active ones."""
    d, J, R = w.d, w.J, w.R
    for j in range(n - 1, q, -1):
        a = d[j - 1]
        b = d[j]
        if b == 0.0:
            continue
        h = math.sqrt(a * a + b * b)
        c = a / h
        s = b / h
        d[j - 1] = h
        d[j] = 0.0
        _rotate_columns(J, j - 1, j, c, s)
    if d[q] == 0.0:
        return False
    for i in range(q + 1):
        R[i, q] = d[i]
    return True


@jitable
def _drop(w: Work, k: int, q: int) -> None:
    """Remove active constraint k of q: shift R's later columns left and restore its upper
    triangle with Givens rotations (applied to J's columns alike), and the multipliers and
    rows with it."""
    R, J, u, active = w.R, w.J, w.u, w.active
    for j in range(k, q - 1):
        active[j] = active[j + 1]
        u[j] = u[j + 1]
        for i in range(j + 2):
            R[i, j] = R[i, j + 1]
    for j in range(k, q - 1):
        a = R[j, j]
        b = R[j + 1, j]
        if b == 0.0:
            continue
        h = math.sqrt(a * a + b * b)
        c = a / h
        s = b / h
        for col in range(j, q - 1):
            ra = R[j, col]
            rb = R[j + 1, col]
            R[j, col] = c * ra + s * rb
            R[j + 1, col] = -s * ra + c * rb
        R[j + 1, j] = 0.0
        _rotate_columns(J, j, j + 1, c, s)
    for i in range(q):
        R[i, q - 1] = 0.0


@jitable
def _directions(w: Work, C: Array, p: int, sign: float, soft: float, width: int, q: int,
                n: int) -> tuple[float, float]:
    """For the normal n_p = sign C[p, :width] (+ soft on x[n - 1]): d = J' n_p, the primal
    step z = J[:, q:] d[q:], the dual step r = R[:q, :q]^-1 d[:q]; returns z' n_p
    (= |d[q:]|^2) and |d|^2 (the normal's size in G^-1's metric)."""
    d, z, r, J, R = w.d, w.z, w.r, w.J, w.R
    dd = 0.0
    for j in range(n):
        acc = 0.0
        for i in range(width):
            acc += J[j, i] * C[p, i]
        acc = sign * acc + soft * J[j, n - 1]
        d[j] = acc
        dd += acc * acc
    for i in range(n):
        z[i] = 0.0
    for j in range(q, n):
        dj = d[j]
        for i in range(n):
            z[i] += J[j, i] * dj
    for i in range(q - 1, -1, -1):
        acc = d[i]
        for j in range(i + 1, q):
            acc -= R[i, j] * r[j]
        r[i] = acc / R[i, i]
    zn = 0.0
    for i in range(width):
        zn += z[i] * C[p, i]
    return sign * zn + soft * z[n - 1], dd


@jitable
def _row_value(C: Array, k: int, width: int, x: Array) -> float:
    acc = 0.0
    for i in range(width):
        acc += C[k, i] * x[i]
    return acc


@jitable
def _unconstrained(J: Array, g: Array, x: Array, d: Array, n: int) -> None:
    """x = -J J' g, the unconstrained minimiser (d: scratch; J transposed, ``Work.J``)."""
    for j in range(n):
        acc = 0.0
        for i in range(n):
            acc += J[j, i] * g[i]
        d[j] = acc
    for i in range(n):
        x[i] = 0.0
    for j in range(n):
        dj = d[j]
        for i in range(n):
            x[i] -= J[j, i] * dj


@jitable
def _bound_value(lo: Array, hi: Array, bound: int) -> float:
    """The right-hand side b of a bound as GI's n' x >= b: lo[k] for 2 k, -hi[k] for
    2 k + 1."""
    k = bound // 2
    return float(lo[k]) if bound % 2 == 0 else float(-hi[k])


@jitable
def _warm(g: Array, C: Array, lo: Array, hi: Array, width: NDArray[np.int64],
          soft: Array, meq: int, m: int, x: Array, w: Work, guess: NDArray[np.int64],
          guessed: int) -> tuple[int, int]:
    """GI's starting point from a guessed active set: J, R factored for the equalities and
    the guessed bounds (each lower 2 k or upper 2 k + 1 of an inequality row k; a bound
    that is infinite, repeated, of a row out of range or dependent on those before it is
    skipped), x the minimiser with them all as equalities, then every guessed bound of
    negative multiplier dropped (and x, u recomputed, and again) until every inequality's
    multiplier is >= 0: x is then optimal for its active set, the invariant ``solve``'s
    iterations keep (the set shrinks at every round, so the rounds end). Returns (q,
    factor updates), or (-1, 0) if an equality is dependent on those before it (``solve``
    then starts cold, as without a guess).

    x = J y with y[:q] = R^-T b (the active bounds' right-hand sides) and y[q:] = -(J' g)[q:],
    u = R^-1 (y[:q] + (J' g)[:q]) (from G x + g = N_A u, J' G = J^-1 and J' N_A = [R; 0]).
    """
    n = g.shape[0]
    J, R, d, z, r, u, active = w.J, w.R, w.d, w.z, w.r, w.u, w.active
    q = 0
    updates = 0
    for e in range(meq + guessed):
        if e < meq:
            bound = 2 * e
            row_soft = 0.0
        else:
            bound = guess[e - meq]
            p = bound // 2
            if bound < 0 or p < meq or p >= m or math.isinf(_bound_value(lo, hi, bound)):
                continue
            repeated = False
            for j in range(q):
                if active[j] // 2 == p:
                    repeated = True
            if repeated:
                continue
            row_soft = soft[p]
        p = bound // 2
        sign = 1.0 if bound % 2 == 0 else -1.0
        dd = 0.0
        tail = 0.0
        for j in range(n):
            acc = 0.0
            for i in range(width[p]):
                acc += J[j, i] * C[p, i]
            acc = sign * acc + row_soft * J[j, n - 1]
            d[j] = acc
            dd += acc * acc
            if j >= q:
                tail += acc * acc
        if tail <= DEPENDENT * dd or not _add(w, q, n):
            if e < meq:
                return -1, 0
            continue
        active[q] = bound
        q += 1
        updates += 1
    while True:
        for j in range(n):  # d = J' g
            acc = 0.0
            for i in range(n):
                acc += J[j, i] * g[i]
            d[j] = acc
        for i in range(q):  # R' y[:q] = b (R' lower triangular)
            acc = _bound_value(lo, hi, active[i])
            for j in range(i):
                acc -= R[j, i] * r[j]
            r[i] = acc / R[i, i]
        for i in range(q, n):
            r[i] = -d[i]
        for i in range(n):  # x = J y
            x[i] = 0.0
        for j in range(n):
            rj = r[j]
            for i in range(n):
                x[i] += J[j, i] * rj
        for i in range(q):
            z[i] = r[i] + d[i]
        for i in range(q - 1, -1, -1):  # u = R^-1 (y[:q] + d[:q])
            acc = z[i]
            for j in range(i + 1, q):
                acc -= R[i, j] * u[j]
            u[i] = acc / R[i, i]
        dropped = 0
        for i in range(q - 1, -1, -1):  # every negative one at once, the last first
            if active[i] >= 2 * meq and u[i] < 0.0:
                _drop(w, i, q)
                q -= 1
                dropped += 1
        if dropped == 0:
            return q, updates
        updates += dropped


@jitable
def solve(J0: Array, g: Array, C: Array, lo: Array, hi: Array, width: NDArray[np.int64],
          soft: Array, meq: int, m: int, x: Array, w: Work, max_iterations: int
          ) -> tuple[int, int, int]:
    """Minimise 1/2 x' G x + g' x subject to the m rows of C (module docstring), from the
    unconstrained minimiser (``solve_warm`` with no guess)."""
    return solve_warm(J0, g, C, lo, hi, width, soft, meq, m, x, w, max_iterations,
                      w.active, 0)


@jitable
def solve_warm(J0: Array, g: Array, C: Array, lo: Array, hi: Array,
               width: NDArray[np.int64], soft: Array, meq: int, m: int, x: Array, w: Work,
               max_iterations: int, guess: NDArray[np.int64], guessed: int
               ) -> tuple[int, int, int]:
    """Minimise 1/2 x' G x + g' x subject to the m rows of C (module docstring), started
    from the bounds guess[:guessed] taken as active (``_warm``): the same minimiser as
    from no guess (the problem is strictly convex), in fewer iterations where the guess is
    close to the final active set.

    Parameters
    ----------
    J0 : (n, n) ``factor(G)``
    g : (n,) linear term
    C : (>= m, n) the constraints' rows (row k read in its first width[k] columns)
    lo, hi : (>= m,) their bounds (-inf, inf: none); the first ``meq`` rows are equalities
        C[k] x = lo[k]
    width : (>= m,) columns read of each row; soft : (>= m,) 1.0 where x[n - 1] (a slack)
        is added to both sides of an inequality (C x + s >= lo, C x - s <= hi), else 0.0
    x : (n,) written: the minimiser (or the last iterate if not OPTIMAL)
    w : ``work(n, >= m)`` buffers; on return w.active[:q] are the active bounds (2 k: row
        k's lower bound, 2 k + 1 its upper bound; an equality as either, the side its
        multiplier belongs to) and w.u[:q] their multipliers (>= 0 for inequalities)
    max_iterations : most constraints added and dropped in all (the guess's included)
    guess : (>= guessed,) bounds guessed active (as w.active's: 2 k lower, 2 k + 1 upper
        bound of inequality row k; not w.active itself unless ``guessed`` is 0)

    Returns
    -------
    (status, iterations, q): ``OPTIMAL``, ``INFEASIBLE`` or ``MAX_ITERATIONS``; the
    constraints added and dropped; the active ones
    """
    n = g.shape[0]
    J, d, z, r, u, active, norms = w.J, w.d, w.z, w.r, w.u, w.active, w.norms
    for i in range(n):
        for j in range(n):
            J[i, j] = J0[i, j]
    for k in range(m):
        acc = soft[k] * soft[k]
        for i in range(width[k]):
            acc += C[k, i] * C[k, i]
        norms[k] = math.sqrt(acc) if acc > 0.0 else 1.0
    q = 0
    iterations = 0
    added_equalities = 0
    if guessed > 0:
        q, iterations = _warm(g, C, lo, hi, width, soft, meq, m, x, w, guess, guessed)
        if q >= 0:
            added_equalities = meq
        else:  # an equality dependent on those before it: from the start, as cold
            q = 0
            iterations = 0
            for i in range(n):
                for j in range(n):
                    J[i, j] = J0[i, j]
    if guessed <= 0 or added_equalities < meq:
        _unconstrained(J, g, x, d, n)
    while True:
        # the bound to add: the next equality, else the most violated inequality bound
        if added_equalities < meq:
            p = added_equalities
            added_equalities += 1
            value = _row_value(C, p, width[p], x) - lo[p]
            sign = -1.0 if value > 0.0 else 1.0  # make it "violated": s_p <= 0
            s_p = sign * value
            bound = 2 * p if sign > 0.0 else 2 * p + 1  # its normal's sign, as a bound's
            equality = True
        else:
            bound = -1
            worst = -TOLERANCE
            s_p = 0.0
            for k in range(meq, m):
                value = _row_value(C, k, width[k], x)
                relief = soft[k] * x[n - 1]
                low = value + relief - lo[k]
                high = hi[k] - value + relief
                scale = norms[k]
                if low < worst * scale or high < worst * scale:
                    side = 0 if low < high else 1
                    candidate = 2 * k + side
                    is_active = False
                    for j in range(q):
                        if active[j] == candidate:
                            is_active = True
                    if not is_active:
                        s_p = low if side == 0 else high
                        worst = s_p / scale
                        bound = candidate
            if bound < 0:
                return OPTIMAL, iterations, q
            p = bound // 2
            sign = 1.0 if bound % 2 == 0 else -1.0
            equality = False
        u_p = 0.0
        row_soft = 0.0 if equality else soft[p]
        while True:  # steps until bound p is active
            if iterations >= max_iterations:
                return MAX_ITERATIONS, iterations, q
            zn, dd = _directions(w, C, p, sign, row_soft, width[p], q, n)
            t1 = math.inf  # the partial (dual) step: an active inequality's multiplier to 0
            drop = -1
            for j in range(q):
                if active[j] >= 2 * meq and r[j] > 0.0:
                    ratio = u[j] / r[j]
                    if ratio < t1:
                        t1 = ratio
                        drop = j
            # no primal step where n_p is (numerically) a combination of the active normals
            t2 = -s_p / zn if zn > DEPENDENT * dd else math.inf
            t = min(t1, t2)
            if math.isinf(t):
                if equality and abs(s_p) <= TOLERANCE * norms[p]:
                    break  # an equality already met and implied by the active ones
                return INFEASIBLE, iterations, q
            for j in range(q):
                u[j] -= t * r[j]
            u_p += t
            iterations += 1
            if math.isinf(t2):  # no primal step: drop and try again
                _drop(w, drop, q)
                q -= 1
                continue
            for i in range(n):
                x[i] += t * z[i]
            if t == t2:  # full step: p becomes active
                if not _add(w, q, n):
                    return INFEASIBLE, iterations, q
                active[q] = bound
                u[q] = u_p
                q += 1
                break
            _drop(w, drop, q)  # partial step: an active constraint leaves first
            q -= 1
            value = _row_value(C, p, width[p], x)
            if equality:
                s_p = sign * (value - lo[p])
            elif sign > 0.0:
                s_p = value + row_soft * x[n - 1] - lo[p]
            else:
                s_p = hi[p] - value + row_soft * x[n - 1]
