"""flatcli's robots as python-control flat systems (``flatcli.flatsystem``).

``flatsystem(spec, overrides)`` returns a ``control.flatsys.FlatSystem`` whose ``forward`` and
``reverse`` are flatcli's own flat maps (``flatcli.core.models.flatmodel``: the paper's closed forms
for N = 2, the chain's for N >= 3), so ``control.flatsys.point_to_point``,
``solve_flat_ocp`` and python-control's simulation (``control.input_output_response``) work on
flatcli's robots. For every design with closed-form flat outputs (``flatcli design``:
``closed_form``); any other is refused with the reason.

The system, for N joints (python-control's names in brackets):

* state x (2 N) = th0..thN [rad], then th1'..th(N-1)' [rad/s], the prolonged inner rates
  (``theta0``.., ``theta1_dot``..);
* input u (N) = th1''..th(N-1)'' [rad/s^2], then thN' [rad/s] (``theta1_ddot``..,
  ``thetaN_dot``);
* flat outputs y1..yN [rad], each with the flag (y, y', y''): y_j = th_j (j < N),
  y_N = th0 + I_N th_N / h_0(q) (for N = 2 the paper's y2 = th0 - c0 th2 / A);
* ``updfcn``: th0' from the model's momentum constraint with H = 0, the other rates from x
  and u; the output is the flat outputs.

The maps are singular where the margin is zero (N = 2: sin(y1) y1' = 0; N >= 3: D =
dh_0/dt = 0): ``reverse`` gives inf or nan there. So a python-control plan must keep y1' (for
N = 2) away from zero and sin(y1) from zero over the whole maneuver, and the flag at both ends
must lie off the singular set: **rest to rest cannot be expressed** (at rest the inner rates
are zero, so the margin is zero and the flag does not determine th_N); flatcli plans rest to
rest itself (``docs/tasks.md``). python-control imposes y'' at both ends as well, which
flatcli's cubic leaves free: ``end_inputs`` gives the inputs of a flatcli plan's own ends.

python-control is an optional extra (``pip install 'flatcli[control]'``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core.errors import FlatcliError

if TYPE_CHECKING:
    from flatcli.api import Overrides, SpecLike
    from flatcli.core.models.flatmodel import FlatModel
    from flatcli.core.plan.planning import Plan

Array = NDArray[np.float64]
#: Complex-step size of ``accelerations`` (exact to rounding: no difference is taken).
STEP = 1e-30
#: What a user without python-control is told.
MISSING = ("flatcli.flatsystem needs python-control, an optional extra: pip install "
           "'flatcli[control]' (or pip install control)")


def _control() -> Any:
    try:
        import control.flatsys as fs
    except ImportError:
        raise FlatcliError(MISSING) from None
    return fs


def flags_of(zflag: Any, n: int) -> Array:
    """python-control's zflag (N lists y_i, y_i', y_i'') as flatcli's flag row (1, 3 N):
    y (N), y' (N), y'' (N)."""
    rows = np.asarray([np.asarray(z, dtype=float)[:3] for z in zflag])
    if rows.shape != (n, 3):
        raise FlatcliError(f"flatsystem: expected {n} flat flags of y, y', y'', got "
                           f"shape {rows.shape}")
    return np.ascontiguousarray(rows.T.reshape(1, 3 * n))


def reverse_map(model: FlatModel, flags: Array) -> tuple[Array, Array]:
    """The states x (m, 2 N) and inputs u (m, N) at flat flags (m, 3 N) (``flags_to_states``)."""
    n = model.n_joints
    theta, theta_dot, u_dot, _ = model.flags_to_states(flags)
    x = np.concatenate([theta, theta_dot[:, 1:n]], axis=1)
    u = np.concatenate([u_dot, theta_dot[:, n:]], axis=1)
    return x, u


def forward_map(model: FlatModel, x: Array, u: Array) -> Array:
    """Flat flags (m, 3 N) at states x (m, 2 N) and inputs u (m, N): y and y' from the
    model's forward map (``outputs``); y_j'' = u_j (j < N); y_N'' from the inverse map,
    which is affine in it: th_N' = (y_N'' - alpha) / beta, so one complex step along y_N''
    (``flag_values``, complex-step safe) gives 1 / beta and -alpha / beta exactly."""
    n = model.n_joints
    theta, rates = x[:, :n + 1], x[:, n + 1:]
    y, y_dot, _ = model.outputs(np.ascontiguousarray(theta), np.ascontiguousarray(rates))
    y_ddot = np.zeros_like(y, dtype=complex)
    y_ddot[:, :n - 1] = u[:, :n - 1]
    y_ddot[:, n - 1] = 1j * STEP
    probe = np.concatenate([y, y_dot, y_ddot], axis=1)
    with np.errstate(all="ignore"):
        rate = model.flag_values(np.ascontiguousarray(probe.T))[2 * n]  # th_N' (complex)
    slope = rate.imag / STEP  # 1 / beta
    last = (u[:, n - 1] - rate.real) / slope
    return np.concatenate([y, y_dot, y_ddot.real[:, :n - 1], last[:, None]], axis=1)


def base_rate(model: FlatModel, theta: Array, rates: Array) -> float:
    """th0' [rad/s] the model's momentum constraint (H = 0) gives at angles theta (N + 1,)
    and joint rates th1'..thN' (N,): the reduced constraint's coefficients for the paper's
    model, the chain's weights h_j otherwise."""
    from flatcli.core.models.flatmodel import ChainModel, PaperModel

    if isinstance(model, PaperModel):
        from flatcli.core.robots.params import base_rate as paper_rate

        return float(paper_rate(model.coefficients, 1.0, 0.0, theta[1], theta[2], rates[0],
                                rates[1]))
    assert isinstance(model, ChainModel)
    from flatcli.core.robots.chain import momentum_weights

    h = np.empty(theta.shape[0])
    momentum_weights(model.K, model.inertia, np.ascontiguousarray(theta, dtype=float), h)
    return float(-(h[1:] @ rates) / h[0])


def flatsystem(spec: SpecLike = None, overrides: Overrides = None) -> Any:
    """The robot of a spec as a python-control ``FlatSystem`` (module docstring).

    Parameters
    ----------
    spec : a spec file, dict or Spec (None: the paper's example), as ``flatcli.plan`` takes
    overrides : dotted keys applied after it (``{"robot.com": [0.1, 0.1, 0.0]}``)

    Returns
    -------
    control.flatsys.FlatSystem with 2 N states, N inputs and N flat outputs

    Raises
    ------
    FlatcliError : python-control missing; a design without closed-form flat outputs
    """
    fs = _control()
    from flatcli.api import load_spec
    from flatcli.core.models.flatmodel import flat_model
    from flatcli.core.robots.params import require_flat
    from flatcli.experiment import checked, robot_from

    s = load_spec(spec, overrides)
    robot = robot_from(s)
    if robot.com_across != 0.0:
        raise FlatcliError("flatsystem: robot.com_across is not 0: the closed-form flat "
                           "outputs need the last link's centre of mass on its joint")
    try:
        require_flat(robot)
    except FlatcliError as exc:
        raise FlatcliError(f"flatsystem: {exc}") from None
    model = flat_model(robot, checked(s.robot.model))
    n = model.n_joints

    def forward(x: Any, u: Any, params: Any = None) -> list[Array]:
        flag = forward_map(model, np.asarray(x, dtype=float).reshape(1, 2 * n),
                           np.asarray(u, dtype=float).reshape(1, n))[0]
        return [np.array([flag[j], flag[n + j], flag[2 * n + j]]) for j in range(n)]

    def reverse(zflag: Any, params: Any = None) -> tuple[Array, Array]:
        x, u = reverse_map(model, flags_of(zflag, n))
        return x[0], u[0]

    def updfcn(t: float, x: Any, u: Any, params: Any = None) -> Array:
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        theta = x[:n + 1]
        rates = np.concatenate([x[n + 1:], u[n - 1:]])
        return np.concatenate([[base_rate(model, theta, rates)], rates, u[:n - 1]])

    return fs.flatsys(
        forward, reverse, updfcn,
        states=[f"theta{a}" for a in range(n + 1)] + [f"theta{j}_dot" for j in range(1, n)],
        inputs=[f"theta{j}_ddot" for j in range(1, n)] + [f"theta{n}_dot"],
        outputs=[f"y{j}" for j in range(1, n + 1)],
        name=s.name)


def end_inputs(plan: Plan) -> tuple[Array, Array]:
    """The inputs u (N,) at t = 0 and t = T of a flatcli plan (from its flag there), which
    ``point_to_point`` needs with the states: th1''..th(N-1)'' [rad/s^2], thN' [rad/s]."""
    ends = np.array([0.0, plan.duration])
    flags = plan.trajectory.flags(ends)
    _, u = reverse_map(plan.model, np.ascontiguousarray(flags))
    return u[0], u[1]


def end_states(plan: Plan) -> tuple[Array, Array]:
    """The states x (2 N,) at t = 0 and t = T of a flatcli plan."""
    ends = np.array([0.0, plan.duration])
    x, _ = reverse_map(plan.model, np.ascontiguousarray(plan.trajectory.flags(ends)))
    return x[0], x[1]
