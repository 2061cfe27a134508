"""Closed-form minimum time-jerk prediction (docs/MATH.md section 1).

Every robot predicts each other robot's trajectory from the state and goal it last
received: the minimum of  J = integral_0^T (|jerk|^2 + w) dt  over quintic trajectories
and the horizon T.  For a given T the optimal quintic is closed form; T is the positive
root of a sextic P(T) = T^6 dJ/dT of least cost J.

Two end-state kinds (selected per lane by ``full``):

* free end (position only; the paper's case): v(T), a(T) free.
* fully defined end (``full=True``): v(T) = vf, a(T) = af; rest-to-rest is vf = af = 0.

Root finding works under jit and vmap on CPU and GPU (no eigvals): J is evaluated on a
log-spaced grid of T spanning bounds on the roots of P (Fujiwara's bound and its reverse,
i.e. the Newton polygon of P), then the bracket around the best grid point is refined
by safeguarded Newton on P (bisection whenever a Newton step leaves the bracket).  The
result is never worse than the best grid point.

Degenerate and bad input (documented behaviour):

* At the goal (D = 0 and nothing to correct: every coefficient of P except w T^6 is 0):
  T = 0 and a hold trajectory at p0.
* Non-finite input in the jitted core: the lane returns a hold trajectory (T = 0) at p0
  with non-finite entries of p0 replaced by 0, so no NaN ever leaves.  The public
  :func:`predict` raises ``ValueError`` naming the argument when given concrete
  non-finite values.
* Input so large that the cost overflows float64 (moves beyond ~1e50 m) is treated like
  non-finite input.

Predicted trajectories coast at their end velocity after T (free end, or a given goal
velocity) or hold their end position (rest end): ``Trajectory.coast``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.trajectory import Trajectory

GRID_POINTS = 64
NEWTON_STEPS = 4


# Performance note: everything below works on lists of per-axis / per-coefficient arrays
# whose only axes are the batch, and loops (unrolled, with a carry) over small fixed
# dimensions such as the T grid.  On XLA:CPU this is ~10x faster than arrays with a
# trailing axis of 3, 5 or 64, which vectorize poorly.


# ---------------------------------------------------------------------- cost pieces
def _quartic_terms(p0, v0, a0, pf, vf, af, full):
    """Per-axis arrays (...,) in, the five summed quartic coefficients (...,) out."""
    f = [0.0] * 5
    g = [0.0] * 5
    for d in range(len(p0)):
        D = pf[d] - p0[d]
        v, a, V, A = v0[d], a0[d], vf[d], af[d]
        f[0] = f[0] + 20.0 * D * D
        f[1] = f[1] - 40.0 * D * v
        f[2] = f[2] + 20.0 * (v * v - D * a)
        f[3] = f[3] + 20.0 * v * a
        f[4] = f[4] + 5.0 * a * a
        g[0] = g[0] + 720.0 * D * D
        g[1] = g[1] - 720.0 * (v + V) * D
        g[2] = g[2] + 3.0 * (64.0 * v * v + 112.0 * v * V + 64.0 * V * V - 40.0 * (a - A) * D)
        g[3] = g[3] + 24.0 * (3.0 * a * v + 2.0 * a * V - 2.0 * A * v - 3.0 * A * V)
        g[4] = g[4] + 3.0 * (3.0 * a * a - 2.0 * a * A + 3.0 * A * A)
    return [jnp.where(full, gk, fk) for fk, gk in zip(f, g, strict=True)]


def _axes(x):
    return [x[..., d] for d in range(x.shape[-1])]


def cost_quartic(p0, v0, a0, pf, vf, af, full):
    """Coefficients q (..., 5) with J(T) = w T + (q0 + q1 T + ... + q4 T^4) / T^5.

    docs/MATH.md 1a (free end: 20 |D - v0 T - a0 T^2/2|^2) and 1b (fully defined end),
    summed over the last (spatial) axis of the inputs (..., N).  ``full`` (...,) bool
    selects the fully defined end state.
    """
    args = [_axes(jnp.asarray(x)) for x in (p0, v0, a0, pf, vf, af)]
    return jnp.stack(_quartic_terms(*args, jnp.asarray(full)), axis=-1)


def cost(T, q, w):
    """J(T) = w T + Q(T) / T^5 for quartic coefficients q (..., 5); T (...,) > 0."""
    Q = q[..., 0] + T * (q[..., 1] + T * (q[..., 2] + T * (q[..., 3] + T * q[..., 4])))
    return w * T + Q / T**5


def _cost_u(T, u, q, w):
    """J at T with u = 1/T, for a list q of five arrays."""
    return w * T + u * (q[4] + u * (q[3] + u * (q[2] + u * (q[1] + u * q[0]))))


def sextic(q, w):
    """Coefficients (..., 7), lowest power first, of P(T) = T^6 dJ/dT.

    P(T) = w T^6 - sum_k (5 - k) q_k T^k  (there is no T^5 term).
    """
    w = jnp.broadcast_to(jnp.asarray(w, q.dtype), q.shape[:-1])
    return jnp.stack(_sextic_terms([q[..., k] for k in range(5)], w), axis=-1)


def _sextic_terms(q, w):
    return [-(5.0 - k) * q[k] for k in range(5)] + [jnp.zeros_like(w), w]


def _poly_and_deriv(a, x):
    """P(x), P'(x) for a list a of coefficient arrays (lowest power first)."""
    p = a[-1]
    dp = jnp.zeros_like(x)
    for i in range(len(a) - 2, -1, -1):
        dp = dp * x + p
        p = p * x + a[i]
    return p, dp


def root_bounds(a):
    """(lo, hi) bounds on the magnitudes of the nonzero roots of P (coefficients a (..., K)).

    Fujiwara's bound for the upper limit; the same bound applied to the reversed
    polynomial (from the lowest nonzero coefficient) for the lower limit.  Computed
    through logarithms.  ``lo = hi = 0`` when P has no nonzero root (only its leading
    coefficient is nonzero).
    """
    lo, hi = _root_bounds_terms([a[..., k] for k in range(a.shape[-1])])
    return lo, hi


def _root_bounds_terms(a):
    K = len(a)
    n = K - 1
    nz = [ak != 0 for ak in a]
    logm = [jnp.log(jnp.where(z, jnp.abs(ak), 1.0)) for ak, z in zip(a, nz, strict=True)]
    # upper: 2 max_{k<n} (|a_k| / |a_n|)^(1/(n-k)), the a_0 term halved
    log_hi = jnp.full_like(logm[0], -jnp.inf)
    for k in range(n):
        half = np.log(0.5) if k == 0 else 0.0
        term = (logm[k] + half - logm[n]) / (n - k)
        log_hi = jnp.where(nz[k], jnp.maximum(log_hi, term), log_hi)
    log_hi = log_hi + np.log(2.0)
    # lower: from the lowest nonzero coefficient m: 1/|z| <= 2 max_{k>m} (|a_k|/|a_m|)^(1/(k-m))
    # found by scanning from the top: the last assignment wins, i.e. the lowest nonzero m.
    log_lo = jnp.zeros_like(logm[0])
    found = jnp.zeros(logm[0].shape, bool)
    for m in range(n - 1, -1, -1):
        best = jnp.full_like(logm[0], -jnp.inf)
        for k in range(m + 1, K):
            term = (logm[k] - logm[m]) / (k - m)
            best = jnp.where(nz[k], jnp.maximum(best, term), best)
        log_lo = jnp.where(nz[m], -np.log(2.0) - best, log_lo)
        found = found | nz[m]
    lo = jnp.where(found, jnp.exp(jnp.where(found, log_lo, 0.0)), 0.0)
    hi = jnp.where(found, jnp.exp(jnp.where(found, log_hi, 0.0)), 0.0)
    return lo, hi


def optimal_horizon(q, w, grid_points: int = GRID_POINTS, newton_steps: int = NEWTON_STEPS):
    """The least-cost positive root T* of the sextic, for quartic cost coefficients q.

    J is evaluated on a geometric grid of ``grid_points`` over [lo, hi] (bounds on every
    positive root, :func:`root_bounds`); the bracket around the best grid point is
    refined by ``newton_steps`` of safeguarded Newton on P (bisection whenever a step
    leaves the bracket).  The result is never worse (in J) than the best grid point.

    Args:
        q: (..., 5) from :func:`cost_quartic`.
        w: () or (...,) time weight > 0.
    Returns:
        T (...,) seconds, 0 where there is no positive root (at the goal).
    """
    w = jnp.broadcast_to(jnp.asarray(w, q.dtype), q.shape[:-1])
    return _horizon_terms([q[..., k] for k in range(5)], w, grid_points, newton_steps)


def _horizon_terms(q, w, grid_points=GRID_POINTS, newton_steps=NEWTON_STEPS):
    a = _sextic_terms(q, w)
    lo, hi = _root_bounds_terms(a)
    has = hi > 0
    lo = jnp.where(has, lo, 1.0)
    hi = jnp.where(has, hi, 2.0)
    r = jnp.exp(jnp.log(hi / lo) / (grid_points - 1))
    ir = 1.0 / r
    inf = jnp.full_like(lo, jnp.inf)

    # Scan the grid with a running minimum, keeping its neighbours and their costs.
    def scan_body(_, c):
        T, u, prevT, prevJ, bT, bJ, loT, loJ, hiT, hiJ, after = c
        J = _cost_u(T, u, q, w)
        J = jnp.where(jnp.isnan(J), jnp.inf, J)
        hiT = jnp.where(after, T, hiT)  # the point right after the current best
        hiJ = jnp.where(after, J, hiJ)
        better = J < bJ
        loT = jnp.where(better, prevT, loT)
        loJ = jnp.where(better, prevJ, loJ)
        bT = jnp.where(better, T, bT)
        bJ = jnp.where(better, J, bJ)
        return T * r, u * ir, T, J, bT, bJ, loT, loJ, hiT, hiJ, better

    init = (lo, 1.0 / lo, 0.5 * lo, inf, lo, inf, 0.5 * lo, inf, 2.0 * hi, inf,
            jnp.zeros(lo.shape, bool))
    out = jax.lax.fori_loop(0, grid_points, scan_body, init, unroll=True)
    _, _, _, _, Tk, Jk, blo, Jlo, bhi, Jhi, after = out
    bhi = jnp.where(after, 2.0 * hi, bhi)  # the best was the last grid point
    Jhi = jnp.where(after, jnp.inf, Jhi)
    Tk = jnp.where(jnp.isfinite(Jk), Tk, lo)  # every J was NaN / inf: start anywhere
    # Vertex of the parabola through the three points: a start within ~1e-3 of the root,
    # so that a few Newton steps reach round-off.
    d1 = (Tk - blo) * (Jk - Jhi)
    d2 = (Tk - bhi) * (Jk - Jlo)
    den = d1 - d2
    step = 0.5 * ((Tk - blo) * d1 - (Tk - bhi) * d2) / jnp.where(den != 0, den, 1.0)
    x0 = Tk - step
    x0 = jnp.where(jnp.isfinite(x0) & (den != 0) & (x0 > blo) & (x0 < bhi), x0, Tk)

    def newton_body(_, c):
        x, blo, bhi = c
        p, dp = _poly_and_deriv(a, x)
        # at a local minimum of J, P = T^6 J' goes from negative to positive
        blo = jnp.where(p < 0, x, blo)
        bhi = jnp.where(p > 0, x, bhi)
        xn = jnp.where(p == 0, x, x - p / dp)
        ok = jnp.isfinite(xn) & (xn >= blo) & (xn <= bhi)
        return jnp.where(ok, xn, 0.5 * (blo + bhi)), blo, bhi

    x, _, _ = jax.lax.fori_loop(0, newton_steps, newton_body, (x0, blo, bhi), unroll=True)
    Jx = _cost_u(x, 1.0 / x, q, w)
    T = jnp.where(jnp.isfinite(Jx) & (Jx <= Jk), x, Tk)
    return jnp.where(has, T, 0.0)


# ---------------------------------------------------------------------- trajectories
def quintic_terms(p0, v0, a0, pf, vf, af, full, T):
    """Per-axis lists in; per-axis lists of the six normalized-time coefficients out."""
    out = []
    T2 = T * T
    for d in range(len(p0)):
        D = pf[d] - p0[d]
        r = D - v0[d] * T - 0.5 * a0[d] * T2
        r2T = (vf[d] - v0[d] - a0[d] * T) * T
        r3T2 = (af[d] - a0[d]) * T2
        c3 = jnp.where(full, 10.0 * r - 4.0 * r2T + 0.5 * r3T2, r * (10.0 / 6.0))
        c4 = jnp.where(full, -15.0 * r + 7.0 * r2T - r3T2, r * (-5.0 / 6.0))
        c5 = jnp.where(full, 6.0 * r - 3.0 * r2T + 0.5 * r3T2, r * (1.0 / 6.0))
        out.append([p0[d], v0[d] * T, 0.5 * a0[d] * T2, c3, c4, c5])
    return out


def quintic_coeffs(p0, v0, a0, pf, vf, af, full, T):
    """Normalized-time quintic coefficients (..., N, 6) of the optimal trajectory for T.

    Inputs (..., N) except ``full`` (...,) bool and ``T`` (...,) seconds (> 0).
    """
    args = [_axes(jnp.asarray(x)) for x in (p0, v0, a0, pf, vf, af)]
    rows = quintic_terms(*args, jnp.asarray(full), jnp.asarray(T))
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def predict_arrays(p0, v0, a0, pf, vf, af, full, w=1.0) -> Trajectory:
    """The jit/vmap core of :func:`predict`: arrays in, a one-segment quintic Trajectory out.

    Args:
        p0, v0, a0: (..., N) start state, m, m/s, m/s^2.
        pf, vf, af: (..., N) goal position, velocity, acceleration (vf, af used only where
            ``full``).
        full: (...,) bool, fully defined end state (else position-only, free end).
        w: () or (...,) time weight (> 0).
    Returns:
        Trajectory with batch (...,), S = 1, degree 5; ``coast`` is True for free ends
        and for fully defined ends with a nonzero goal velocity.  Never NaN: non-finite
        lanes become a hold at p0 (non-finite entries replaced by 0).
    """
    arrs = jnp.broadcast_arrays(*(jnp.asarray(x, jnp.float64) for x in (p0, v0, a0, pf, vf, af)))
    batch = arrs[0].shape[:-1]
    N = arrs[0].shape[-1]
    full = jnp.broadcast_to(jnp.asarray(full, bool), batch)
    w = jnp.broadcast_to(jnp.asarray(w, jnp.float64), batch)
    ax = [_axes(x) for x in arrs]
    finite = jnp.isfinite(w) & (w > 0)
    for lst in ax:
        for x in lst:
            finite = finite & jnp.isfinite(x)
    p0, v0, a0, pf, vf, af = ([jnp.where(finite, x, 0.0) for x in lst] for lst in ax)
    ws = jnp.where(finite, w, 1.0)
    q = _quartic_terms(p0, v0, a0, pf, vf, af, full)
    T = _horizon_terms(q, ws)
    ok = finite & (T > 0) & jnp.isfinite(T)
    Ts = jnp.where(ok, T, 1.0)
    rows = quintic_terms(p0, v0, a0, pf, vf, af, full, Ts)
    for row in rows:
        for x in row:
            ok = ok & jnp.isfinite(x)
    p_hold = [jnp.where(jnp.isfinite(x), x, 0.0) for x in ax[0]]
    zero = jnp.zeros(batch, jnp.float64)
    rows = [
        [jnp.where(ok, x, p_hold[d] if i == 0 else zero) for i, x in enumerate(row)]
        for d, row in enumerate(rows)
    ]
    c = jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)[..., None, :, :]
    T = jnp.where(ok, T, 0.0)
    moving_end = jnp.zeros(batch, bool)
    for d in range(N):
        moving_end = moving_end | (vf[d] != 0.0)
    coast = jnp.where(full, moving_end, True) & ok
    return Trajectory.from_normalized(c, T, coast)


def predict(p0, v0, a0, goal, *, end: str = "free", goal_velocity=None, time_weight=1.0):
    """Closed-form minimum time-jerk trajectories from states to goals (docs/MATH.md 1).

    Args:
        p0, v0, a0: (..., N) start position (m), velocity (m/s), acceleration (m/s^2).
        goal: (..., N) goal position, m.
        end: "free" (position only, the paper's case) or "rest" (fully defined end
            state: velocity ``goal_velocity`` (default 0) and zero acceleration).
        goal_velocity: (..., N) m/s, only with end="rest".
        time_weight: w > 0, the price of one second in units of jerk^2 s.
    Returns:
        Trajectory (batch ...), degree 5, one segment; ``duration`` is the optimal T
        (0 for a robot already at rest at its goal: a hold trajectory).
    Raises:
        ValueError naming the argument for non-finite concrete input, a non-positive
        time weight, mismatched shapes, or an unknown ``end``.
    """
    if end not in ("free", "rest"):
        raise ValueError(f"end must be 'free' or 'rest', got {end!r}")
    if goal_velocity is not None and end != "rest":
        raise ValueError("goal_velocity is a fully defined end state: pass end='rest'")
    named = {"p0": p0, "v0": v0, "a0": a0, "goal": goal}
    if goal_velocity is not None:
        named["goal_velocity"] = goal_velocity
    shapes = {}
    for name, x in named.items():
        if isinstance(x, jax.core.Tracer):
            shapes[name] = x.shape
            continue
        arr = np.asarray(x, dtype=np.float64)
        if arr.ndim == 0:
            raise ValueError(f"{name} must have a trailing spatial axis (..., N), got a scalar")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} contains non-finite values (NaN or inf)")
        shapes[name] = arr.shape
    try:
        np.broadcast_shapes(*shapes.values())
    except ValueError:
        raise ValueError(f"shapes do not broadcast: {shapes}") from None
    if len({s[-1] for s in shapes.values()}) != 1:
        raise ValueError(f"spatial dimension differs between arguments: {shapes}")
    if not isinstance(time_weight, jax.core.Tracer):
        tw = np.asarray(time_weight, dtype=np.float64)
        if not np.all(np.isfinite(tw)) or np.any(tw <= 0):
            raise ValueError(f"time_weight must be finite and > 0, got {time_weight!r}")
    vf = goal_velocity if goal_velocity is not None else jnp.zeros_like(jnp.asarray(goal))
    af = jnp.zeros_like(jnp.asarray(goal, jnp.float64))
    full = end == "rest"
    p0, v0, a0, goal, vf, af = jnp.broadcast_arrays(
        *(jnp.asarray(x, jnp.float64) for x in (p0, v0, a0, goal, vf, af))
    )
    return _predict_jit(p0, v0, a0, goal, vf, af, full, time_weight)


@jax.jit
def _predict_jit(p0, v0, a0, pf, vf, af, full, w):
    return predict_arrays(p0, v0, a0, pf, vf, af, full, w)
