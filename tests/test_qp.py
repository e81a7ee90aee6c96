"""The dense QP solver (flatcli/core/controllers/qp.py) against two referees: the ``quadprog``
package (Goldfarb and Idnani's dual method in Fortran, an independent implementation) and the
Karush-Kuhn-Tucker conditions of each problem checked directly (stationarity, primal and
dual feasibility, complementarity), on random problems of every kind the MPC builds:
equalities, two-sided and one-sided bounds, rows read in part (widths), soft rows with a
slack, and infeasible problems. Whether a problem is feasible at all is decided by scipy's
linear programming (HiGHS): quadprog calls some feasible, degenerate problems inconsistent
(hypothesis found one: seed 23316, n = 4, m = 17, meq = 3)."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
import quadprog
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from flatcli.core.controllers import qp

Array = NDArray[np.float64]

#: Agreement with quadprog, relative to the solution's size (both are exact active-set
#: methods: they differ only by rounding).
AGREE = 1e-8
#: The KKT conditions, relative to the problem's scale.
KKT = 1e-8


class Problem:
    """A random QP: G (n, n), g (n,), rows C (m, n) with bounds lo, hi, widths, softness;
    meq equalities first."""

    def __init__(self, seed: int, n: int, m: int, meq: int, soft: bool, feasible: bool) -> None:
        rng = np.random.default_rng(seed)
        a = rng.standard_normal((n, n))
        self.G = a @ a.T + 0.1 * np.eye(n)
        self.g = rng.standard_normal(n)
        self.width = rng.integers(1, n + 1, size=m).astype(np.int64)
        self.soft = np.zeros(m)
        if soft and n >= 2:  # the last variable is a slack that soft rows may use
            self.width = np.minimum(self.width, n - 1)
            self.soft = (rng.random(m) < 0.6).astype(float)
            self.soft[:meq] = 0.0
            self.G[n - 1, :] = 0.0
            self.G[:, n - 1] = 0.0
            self.G[n - 1, n - 1] = 1.0
        C = rng.standard_normal((m, n))
        for k in range(m):
            C[k, self.width[k]:] = 0.0
        self.C = C
        x_feasible = rng.standard_normal(n)
        if soft and n >= 2:
            x_feasible[n - 1] = 0.0
        value = C @ x_feasible
        self.lo = value - np.abs(rng.standard_normal(m)) * (1.0 if feasible else -1.0)
        self.hi = value + np.abs(rng.standard_normal(m))
        self.lo[:meq] = self.hi[:meq] = value[:meq]
        one_sided = rng.random(m) < 0.3
        self.lo[meq:][one_sided[meq:]] = -np.inf
        if soft and n >= 2 and m > meq:  # the slack's own row: s >= 0
            self.C[m - 1] = 0.0
            self.width[m - 1] = 1
            self.lo[m - 1], self.hi[m - 1], self.soft[m - 1] = 0.0, np.inf, 1.0
        self.n, self.m, self.meq = n, m, meq

    def dense(self) -> tuple[Array, Array]:
        """The rows as quadprog takes them: A' x >= b, equalities first."""
        rows, bounds = [], []
        s = np.zeros(self.n)
        if self.n:
            s[self.n - 1] = 1.0
        for k in range(self.m):
            c = self.C[k]
            if k < self.meq:
                rows.append(c)
                bounds.append(self.lo[k])
        for k in range(self.meq, self.m):
            c = self.C[k]
            relief = self.soft[k] * s
            if math.isfinite(self.lo[k]):
                rows.append(c + relief)
                bounds.append(self.lo[k])
            if math.isfinite(self.hi[k]):
                rows.append(-c + relief)
                bounds.append(-self.hi[k])
        if not rows:
            return np.zeros((self.n, 0)), np.zeros(0)
        return np.ascontiguousarray(np.array(rows).T), np.array(bounds)

    def solve(self) -> tuple[int, Array, qp.Work, int]:
        x = np.zeros(self.n)
        w = qp.work(self.n, self.m)
        status, _, q = qp.solve(qp.factor(self.G), self.g, self.C, self.lo, self.hi,
                                self.width, self.soft, self.meq, self.m, x, w, 10_000)
        return status, x, w, q


def is_feasible(p: Problem) -> bool:
    """Whether any x meets the rows: a linear programme with a zero objective (HiGHS)."""
    from scipy.optimize import linprog

    A, b = p.dense()
    if A.shape[1] == 0:
        return True
    eq = slice(0, p.meq)
    ineq = slice(p.meq, A.shape[1])
    result = linprog(np.zeros(p.n), A_ub=-A[:, ineq].T if A.shape[1] > p.meq else None,
                     b_ub=-b[ineq] if A.shape[1] > p.meq else None,
                     A_eq=A[:, eq].T if p.meq else None, b_eq=b[eq] if p.meq else None,
                     bounds=[(None, None)] * p.n, method="highs")
    return bool(result.status == 0)


def quadprog_solution(p: Problem) -> Array | None:
    A, b = p.dense()
    try:
        return np.asarray(quadprog.solve_qp(p.G, -p.g, A, b, p.meq)[0])
    except ValueError:  # "constraints are inconsistent, no solution"
        return None


def check_kkt(p: Problem, x: Array, w: qp.Work, q: int) -> None:
    """Stationarity G x + g = sum of the active normals times their multipliers, the
    multipliers of inequalities >= 0, every row met, the active ones with equality."""
    scale = 1.0 + np.abs(p.g).max() + np.abs(p.G).max() * (1.0 + np.abs(x).max())
    gradient = p.G @ x + p.g
    s = np.zeros(p.n)
    s[p.n - 1] = 1.0
    normals = np.zeros(p.n)
    for j in range(q):
        k, side = divmod(int(w.active[j]), 2)
        sign = 1.0 if side == 0 else -1.0
        normal = sign * p.C[k] + (p.soft[k] * s if k >= p.meq else 0.0)
        normals += w.u[j] * normal
        if k >= p.meq:
            assert w.u[j] >= -KKT * scale
        bound = p.lo[k] if side == 0 else -p.hi[k]
        assert normal @ x - bound == pytest.approx(0.0, abs=KKT * scale)
    np.testing.assert_allclose(gradient, normals, atol=KKT * scale)
    relief = p.soft * x[p.n - 1]
    value = p.C @ x
    assert np.all(value + relief >= p.lo - KKT * scale)
    assert np.all(value - relief <= p.hi + KKT * scale)


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 12), m=st.integers(0, 24),
       soft=st.booleans(), feasible=st.booleans(), data=st.data())
def test_solutions_equal_quadprogs_and_meet_the_kkt_conditions(
        seed: int, n: int, m: int, soft: bool, feasible: bool, data: st.DataObject) -> None:
    meq = data.draw(st.integers(0, min(m, n, 4)))
    p = Problem(seed, n, m, meq, soft, feasible)
    reference = quadprog_solution(p) if p.m else np.linalg.solve(p.G, -p.g)
    status, x, w, q = p.solve()
    if not is_feasible(p):
        assert status == qp.INFEASIBLE
        return
    assert status == qp.OPTIMAL
    check_kkt(p, x, w, q)  # the optimum: the KKT conditions of a strictly convex QP
    if reference is not None:
        np.testing.assert_allclose(x, reference, atol=AGREE * (1.0 + np.abs(reference).max()))


def test_a_problem_quadprog_calls_inconsistent_is_solved() -> None:
    """The case hypothesis found: feasible by HiGHS, inconsistent by quadprog; flatcli's
    solution meets the KKT conditions (the referee that does not depend on quadprog)."""
    rng_case = (23316, 4, 17, 3, True)
    p = Problem(rng_case[0], rng_case[1], rng_case[2], rng_case[3], False, rng_case[4])
    status, x, w, q = p.solve()
    if is_feasible(p):
        assert status == qp.OPTIMAL
        check_kkt(p, x, w, q)
    else:
        assert status == qp.INFEASIBLE


def test_a_soft_row_that_cannot_be_met_is_met_by_its_slack() -> None:
    """Two soft rows that contradict each other (x >= 1 and x <= -1): the slack takes
    exactly the gap (closed form: s = 1, x = 0 by symmetry), where the hard rows are
    infeasible."""
    G = np.diag([1.0, 1.0])
    g = np.array([0.0, 1e3])  # the slack's linear penalty
    C = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
    lo, hi = np.array([1.0, -np.inf, 0.0]), np.array([np.inf, -1.0, np.inf])
    width = np.array([1, 1, 1])
    x = np.zeros(2)
    w = qp.work(2, 3)
    status, _, _ = qp.solve(qp.factor(G), g, C, lo, hi, width, np.ones(3), 0, 3, x, w, 100)
    assert status == qp.OPTIMAL
    np.testing.assert_allclose(x, [0.0, 1.0], atol=1e-12)
    status, _, _ = qp.solve(qp.factor(G), g, C, lo, hi, width, np.zeros(3), 0, 3, x, w, 100)
    assert status == qp.INFEASIBLE


def test_the_iteration_budget_is_reported() -> None:
    p = Problem(7, 8, 20, 0, False, True)
    x = np.zeros(p.n)
    w = qp.work(p.n, p.m)
    status, iterations, _ = qp.solve(qp.factor(p.G), p.g, p.C, p.lo, p.hi, p.width, p.soft,
                                     0, p.m, x, w, 0)
    reference = quadprog_solution(p)
    assert reference is not None and np.abs(p.G @ reference + p.g).max() > 1e-6  # active
    assert (status, iterations) == (qp.MAX_ITERATIONS, 0)


def test_compiled_without_numbas_runtime_gives_the_same_bits() -> None:
    """The solver runs inside kernels compiled without numba's runtime (it allocates
    nothing); compiled, it gives the Python function's numbers to the bit."""
    options = {"_nrt": False}
    compiled = numba.njit(**options)(qp.solve.__wrapped__ if hasattr(qp.solve, "__wrapped__")
                                     else qp.solve)
    for seed in range(20):
        p = Problem(seed, 9, 15, 2, True, seed % 2 == 0)
        status, x, _, _ = p.solve()
        x2 = np.zeros(p.n)
        w2 = qp.work(p.n, p.m)
        status2, _, _ = compiled(qp.factor(p.G), p.g, p.C, p.lo, p.hi, p.width, p.soft,
                                 p.meq, p.m, x2, w2, 10_000)
        assert status2 == status
        assert np.array_equal(x, x2)


def _guesses(p: Problem, right: NDArray[np.int64], kind: str, rng: np.random.Generator
             ) -> NDArray[np.int64]:
    """A guessed active set of ``kind``: the cold solve's own inequality bounds ("right"),
    random bounds of inequality rows ("wrong": either side, some infinite, some repeated),
    or half of the right ones with as many wrong ones, shuffled ("partly")."""
    right = right[right >= 2 * p.meq]
    rows = p.m - p.meq
    count = int(rng.integers(1, p.n + 3)) if rows > 0 else 0
    wrong = 2 * (p.meq + rng.integers(0, max(rows, 1), size=count)) + rng.integers(0, 2, count)
    if kind == "right":
        guess = right
    elif kind == "wrong":
        guess = wrong
    else:
        guess = np.concatenate([rng.permutation(right)[: (len(right) + 1) // 2], wrong])
        guess = rng.permutation(guess)
    return np.ascontiguousarray(guess, dtype=np.int64)


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 12), m=st.integers(0, 24),
       soft=st.booleans(), feasible=st.booleans(),
       kind=st.sampled_from(["right", "wrong", "partly"]), data=st.data())
def test_warm_started_solutions_equal_quadprogs_whatever_the_guess(
        seed: int, n: int, m: int, soft: bool, feasible: bool, kind: str,
        data: st.DataObject) -> None:
    """``solve_warm`` from a guessed active set, right, wrong or partly right, finds the same
    minimiser as quadprog (the problem is strictly convex: one minimiser whatever the start)
    and meets the KKT conditions; infeasible problems are still found infeasible."""
    meq = data.draw(st.integers(0, min(m, n, 4)))
    p = Problem(seed, n, m, meq, soft, feasible)
    _, _, w_cold, q_cold = p.solve()
    guess = _guesses(p, w_cold.active[:q_cold].copy(), kind, np.random.default_rng(seed))
    x = np.zeros(p.n)
    w = qp.work(p.n, p.m)
    status, _, q = qp.solve_warm(qp.factor(p.G), p.g, p.C, p.lo, p.hi, p.width, p.soft,
                                 p.meq, p.m, x, w, 10_000, guess, len(guess))
    if not is_feasible(p):
        assert status == qp.INFEASIBLE
        return
    assert status == qp.OPTIMAL
    check_kkt(p, x, w, q)
    reference = quadprog_solution(p) if p.m else np.linalg.solve(p.G, -p.g)
    if reference is not None:
        np.testing.assert_allclose(x, reference, atol=AGREE * (1.0 + np.abs(reference).max()))


def test_a_right_guess_needs_no_iteration_beyond_its_own_factoring() -> None:
    """Started from the cold solve's own active set, the warm solve adds each guessed bound
    once (the equalities too) and drops none: its iterations are the active set's size,
    fewer than the cold solve's (which also tries bounds that leave again), with
    quadprog's minimiser."""
    p = Problem(11, 12, 24, 2, True, True)
    _, _, w_cold, q_cold = p.solve()
    x = np.zeros(p.n)
    w = qp.work(p.n, p.m)
    cold = qp.solve(qp.factor(p.G), p.g, p.C, p.lo, p.hi, p.width, p.soft, p.meq, p.m,
                    np.zeros(p.n), qp.work(p.n, p.m), 10_000)
    active = w_cold.active[:q_cold]
    guess = np.ascontiguousarray(active[active >= 2 * p.meq])
    status, iterations, q = qp.solve_warm(qp.factor(p.G), p.g, p.C, p.lo, p.hi, p.width,
                                          p.soft, p.meq, p.m, x, w, 10_000, guess,
                                          len(guess))
    assert status == qp.OPTIMAL and q == q_cold and len(guess) > 2
    assert iterations == q_cold < cold[1]
    reference = quadprog_solution(p)
    assert reference is not None
    np.testing.assert_allclose(x, reference, atol=AGREE * (1.0 + np.abs(reference).max()))
