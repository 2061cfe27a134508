"""Reference solver: IPOPT through CasADi on the identical NLP (for tests and benchmarks).

The NLP is jaxplan's own: the objective :func:`jaxplan.nlp.objective` and the inequality
constraints :func:`jaxplan.nlp.constraints` (g >= 0) over the same variables x = (z,
log T), with T >= t_min, the equality constraints eliminated by the same
parametrization.  It is built symbolically in CasADi by tracing those two JAX functions
to a jaxpr and evaluating each of its primitives on CasADi SX expressions
(:func:`jaxpr_to_sx`): the same formula, term for term, as CasADi scalar expressions,
with every NLPParams leaf a CasADi parameter (one solver per structure and number of
other robots, reused for every NLP of that shape).  CasADi then forms the gradient, the
constraint Jacobian and the Hessian of the Lagrangian by its own algorithmic
differentiation on the SX graph (nothing of JAX's derivatives is used), and IPOPT
(bundled with CasADi's wheel, MUMPS as its linear solver) solves with exact second
derivatives.  No Python runs inside IPOPT's iterations: the derivatives are evaluated
by CasADi's SX virtual machine in C++ (``codegen=True`` compiles them to C with the
system's C compiler instead: for the two-segment NLP with 9 other robots gcc -O1 had
not finished compiling it after 5 minutes and 3.6 GB, so the SX virtual machine is what
is measured).

The static rows (obstacles and workspace faces, NLPParams.static) are parameters like
the others: the same tracing covers them.  Primitives that only move elements
(reshape, broadcast, slice, ...) and those on numbers only are evaluated with numpy
where they are the common ones, so that building the SX graph compiles next to no XLA
program.

tests/test_world.py checks, on NLPs with static rows (a pillar and the ground) and
another robot, that CasADi's objective and constraints equal jaxplan's at random
points (to 1e-10 relative) and that IPOPT and jaxplan's solver reach the same optimum;
tests/test_solver.py (slow) the same on NLPs with up to nine others and no static rows.
"""

from __future__ import annotations

import functools
import time
from typing import NamedTuple

import casadi as ca
import jax
import jax.extend.core
import jax.numpy as jnp
import numpy as np

from jaxplan import nlp
from jaxplan.nlp import NLPParams, NLPStructure

# IPOPT's tolerances (see :func:`solve_ipopt`): its scaled KKT error and the constraint
# violation (m^2, as jaxplan's tol_feasibility), no relaxation of the bound on T
IPOPT_TOL = 1e-10
IPOPT_CONSTR_VIOL_TOL = 1e-8
# x0 is a good start (the planner's guess or warm start): IPOPT starts there with a small
# barrier parameter instead of its default 0.1, which first pushes the iterate away from
# the constraints.  On 8 random two-segment NLPs from jaxplan's initial guesses: with
# IPOPT's defaults 20-66 iterations and 2 of 8 in another local minimum (objective 3%
# worse, 15% better); with these 5-19 iterations and all 8 at jaxplan's optimum (relative
# gap <= 5e-11)
IPOPT_START = {"mu_init": 1e-6, "warm_start_init_point": "yes", "warm_start_bound_push": 1e-9,
               "mu_strategy": "adaptive"}


# ---------------------------------------------------------------------- jaxpr -> SX
class _Sym(NamedTuple):
    """A symbolic array: its elements as one SX column (row-major order) and its shape."""

    v: ca.SX
    shape: tuple


def _size(shape) -> int:
    return int(np.prod(shape, dtype=np.int64))


def _as_sx(a) -> ca.SX:
    """An SX column of a symbolic or numeric array's elements (row-major)."""
    if isinstance(a, _Sym):
        return a.v
    return ca.SX(ca.DM(np.asarray(a, np.float64).reshape(-1)))


def _shape(a) -> tuple:
    return a.shape if isinstance(a, _Sym) else np.shape(a)


def _take(v: ca.SX, idx) -> ca.SX:
    """v's elements at the integer array idx, row-major, as an SX column."""
    flat = np.asarray(idx, np.int64).reshape(-1)
    if flat.size == 0:
        return ca.SX(0, 1)
    r = v[[int(i) for i in flat]]
    return r if r.shape[1] == 1 else ca.reshape(r, r.numel(), 1)


def _structural(prim, params, args):
    """A primitive that only moves elements (reshape, slice, broadcast, concatenate...):
    applied to the elements' indices, then the elements taken."""
    cols, idx_args, off = [], [], 0
    for a in args:
        sx = _as_sx(a)
        n = _size(_shape(a))
        cols.append(sx)
        idx_args.append(np.arange(off, off + n, dtype=np.int64).reshape(_shape(a)))
        off += n
    idx = _move(prim, params, idx_args)
    if idx is None:
        idx = np.asarray(prim.bind(*[jnp.asarray(x, jnp.int32) for x in idx_args], **params))
    return _Sym(_take(ca.vertcat(*cols), idx), tuple(idx.shape))


def _move(prim, params, arrays):
    """The structural primitive applied to integer arrays: in numpy where it is one of
    the common ones (no XLA compilation per shape), else None."""
    if not arrays:
        return None
    name, a = prim.name, arrays[0]
    if name == "reshape" and params.get("dimensions") is None:
        return a.reshape(params["new_sizes"])
    if name == "broadcast_in_dim":
        shape, dims = tuple(params["shape"]), tuple(params["broadcast_dimensions"])
        expanded = [1] * len(shape)
        for d, n in zip(dims, a.shape, strict=True):
            expanded[d] = n
        return np.broadcast_to(a.reshape(expanded), shape)
    if name == "squeeze":
        return np.squeeze(a, axis=tuple(params["dimensions"]))
    if name == "expand_dims":
        return np.expand_dims(a, tuple(params["dimensions"]))
    if name == "transpose":
        return np.transpose(a, tuple(params["permutation"]))
    if name == "slice":
        strides = params.get("strides") or (1,) * a.ndim
        return a[tuple(slice(b, e, k) for b, e, k in zip(
            params["start_indices"], params["limit_indices"], strides, strict=True))]
    if name == "concatenate":
        return np.concatenate(arrays, axis=params["dimension"])
    if name == "rev":
        return np.flip(a, axis=tuple(params["dimensions"]))
    if name in ("copy", "copy_p"):
        return a
    if name == "convert_element_type":
        return a.astype(np.dtype(params["new_dtype"]))
    return None


_STRUCTURAL = {"reshape", "broadcast_in_dim", "squeeze", "transpose", "slice", "concatenate",
               "stack", "rev", "expand_dims", "copy", "copy_p", "pad_zero"}


def _unary(name, params):
    return {
        "exp": ca.exp, "log": ca.log, "sqrt": ca.sqrt, "neg": lambda a: -a, "abs": ca.fabs,
        "sin": ca.sin, "cos": ca.cos, "tanh": ca.tanh, "log1p": ca.log1p, "expm1": ca.expm1,
        "sign": ca.sign, "not": ca.logic_not, "square": lambda a: a * a,
        "rsqrt": lambda a: 1.0 / ca.sqrt(a),
        # the parameters are finite (solve_ipopt checks them before it solves)
        "is_finite": lambda a: ca.SX.ones(a.shape),
        "integer_pow": lambda a: _ipow(a, params["y"]),
        "convert_element_type": lambda a: a,
        "stop_gradient": lambda a: a,
    }.get(name)


def _ipow(a, y: int):
    if y == 0:
        return ca.SX.ones(a.shape)
    if y < 0:
        return 1.0 / _ipow(a, -y)
    out = a
    for _ in range(y - 1):
        out = out * a
    return out


_BINARY = {
    "add": lambda a, b: a + b, "sub": lambda a, b: a - b, "mul": lambda a, b: a * b,
    "div": lambda a, b: a / b, "max": ca.fmax, "min": ca.fmin, "pow": ca.power,
    "gt": lambda a, b: a > b, "ge": lambda a, b: a >= b, "lt": lambda a, b: a < b,
    "le": lambda a, b: a <= b, "eq": lambda a, b: a == b, "ne": lambda a, b: a != b,
    "and": ca.logic_and, "or": ca.logic_or, "atan2": ca.atan2,
}


def _broadcast(cols, shapes):
    """Elementwise operands broadcast to their common shape (numpy's rules)."""
    shape = tuple(np.broadcast_shapes(*[tuple(s) for s in shapes]))
    out = []
    for c, s in zip(cols, shapes, strict=True):
        if tuple(s) != shape:
            c = _take(c, np.broadcast_to(np.arange(_size(s)).reshape(s), shape))
        out.append(c)
    return out, shape


def _reduce(name, a, axes):
    shape = _shape(a)
    keep = [d for d in range(len(shape)) if d not in axes]
    idx = np.arange(_size(shape)).reshape(shape).transpose(keep + list(axes))
    out_shape = tuple(shape[d] for d in keep)
    idx = idx.reshape(_size(out_shape), -1)
    v = _as_sx(a)
    op = {"reduce_sum": ca.sum1, "reduce_max": ca.mmax, "reduce_min": ca.mmin,
          "reduce_and": lambda c: ca.mmin(c), "reduce_or": lambda c: ca.mmax(c),
          "reduce_prod": lambda c: functools.reduce(lambda x, y: x * y,
                                                    [c[i] for i in range(c.shape[0])])}[name]
    return _Sym(ca.vertcat(*[op(_take(v, row)) for row in idx]) if idx.shape[0] else ca.SX(0, 1),
                out_shape)


def _dot_general(a, b, dimension_numbers):
    (lc, rc), (lb, rb) = dimension_numbers
    sa, sb = _shape(a), _shape(b)
    lf = [d for d in range(len(sa)) if d not in lc and d not in lb]
    rf = [d for d in range(len(sb)) if d not in rc and d not in rb]
    nb = _size([sa[d] for d in lb])
    nk = _size([sa[d] for d in lc])
    nl, nr = _size([sa[d] for d in lf]), _size([sb[d] for d in rf])
    ia = np.arange(_size(sa)).reshape(sa).transpose(list(lb) + lf + list(lc)).reshape(nb, nl, nk)
    ib = np.arange(_size(sb)).reshape(sb).transpose(list(rb) + list(rc) + rf).reshape(nb, nk, nr)
    va, vb = _as_sx(a), _as_sx(b)
    out = []
    for k in range(nb):
        A = ca.reshape(_take(va, ia[k].T), nl, nk)  # column-major fill
        B = ca.reshape(_take(vb, ib[k].T), nk, nr)
        out.append(ca.vec(ca.mtimes(A, B).T))  # row-major flatten
    shape = tuple([sa[d] for d in lb] + [sa[d] for d in lf] + [sb[d] for d in rf])
    return _Sym(ca.vertcat(*out), shape)


def _select_n(pred, *cases):
    shapes = [_shape(c) for c in cases] + [_shape(pred)]
    cols, shape = _broadcast([_as_sx(c) for c in cases] + [_as_sx(pred)], shapes)
    *cs, p = cols
    if len(cs) != 2:
        raise NotImplementedError("select_n with more than two cases")
    return _Sym(ca.if_else(p, cs[1], cs[0]), shape)


def _eval_eqn(eqn, args):
    prim, params = eqn.primitive, eqn.params
    name = prim.name
    if not any(isinstance(a, _Sym) for a in args):  # numbers only: numpy or JAX computes it
        out = _move(prim, params, [np.asarray(a) for a in args])
        if out is not None:
            return [np.asarray(out)]
        out = prim.bind(*[jnp.asarray(a) for a in args], **params)
        return [np.asarray(o) for o in out] if prim.multiple_results else [np.asarray(out)]
    if name in ("jit", "pjit", "closed_call", "core_call", "custom_jvp_call", "custom_vjp_call",
                "remat", "checkpoint"):
        sub = params.get("jaxpr") or params.get("call_jaxpr") or params.get("fun_jaxpr")
        closed = sub if hasattr(sub, "consts") else None
        jx = closed.jaxpr if closed is not None else sub
        consts = closed.consts if closed is not None else []
        return _eval_jaxpr(jx, consts, args)
    if name in _STRUCTURAL:
        return [_structural(prim, params, args)]
    if name == "select_n":
        return [_select_n(*args)]
    if name == "dot_general":
        return [_dot_general(args[0], args[1], params["dimension_numbers"])]
    if name.startswith("reduce_"):
        return [_reduce(name, args[0], tuple(params["axes"]))]
    if name == "clamp":
        lo, x, hi = args
        return _eval_eqn_binary("min", _eval_eqn_binary("max", x, lo), hi)
    un = _unary(name, params)
    if un is not None and len(args) == 1:
        return [_Sym(un(_as_sx(args[0])), tuple(_shape(args[0])))]
    if name in _BINARY:
        return _eval_eqn_binary(name, *args)
    raise NotImplementedError(f"jaxpr -> CasADi: primitive {name!r}")


def _eval_eqn_binary(name, a, b):
    if isinstance(a, list):
        a = a[0]
    cols, shape = _broadcast([_as_sx(a), _as_sx(b)], [_shape(a), _shape(b)])
    return [_Sym(_BINARY[name](*cols), shape)]


def _eval_jaxpr(jaxpr, consts, args):
    env = {}

    def read(v):
        if isinstance(v, jax.extend.core.Literal):
            return np.asarray(v.val)
        return env[v]

    for v, c in zip(jaxpr.constvars, consts, strict=True):
        env[v] = np.asarray(c)
    for v, a in zip(jaxpr.invars, args, strict=True):
        env[v] = a
    for eqn in jaxpr.eqns:
        outs = _eval_eqn(eqn, [read(v) for v in eqn.invars])
        for v, o in zip(eqn.outvars, outs, strict=True):
            env[v] = o
    return [read(v) for v in jaxpr.outvars]


def jaxpr_to_sx(fn, example_args, sx_args):
    """The outputs of ``fn`` (a JAX function of arrays) as SX columns, its inputs the SX
    columns ``sx_args`` (each with as many elements as the example argument's)."""
    closed = jax.make_jaxpr(fn)(*example_args)
    ins = [_Sym(s, tuple(np.shape(e))) for s, e in zip(sx_args, example_args, strict=True)]
    outs = _eval_jaxpr(closed.jaxpr, closed.consts, ins)
    return [_as_sx(o) for o in outs]


# ---------------------------------------------------------------------- the NLP
def _flat_params(params: NLPParams) -> np.ndarray:
    return np.concatenate([np.asarray(a, np.float64).reshape(-1)
                           for a in jax.tree.leaves(params)])


@functools.cache
def _problem(structure: NLPStructure, treedef, leaf_specs):
    """(x, p, f, g) SX of the NLP of this structure and parameter shapes."""
    shapes = [s for s, _ in leaf_specs]
    n_p = sum(_size(s) for s in shapes)
    x = ca.SX.sym("x", structure.n_x)
    p = ca.SX.sym("p", n_p)
    cuts = np.cumsum([0] + [_size(s) for s in shapes])
    p_cols = [p[int(a):int(b)] for a, b in zip(cuts[:-1], cuts[1:], strict=True)]

    def fg(x, *leaves):
        pp = jax.tree.unflatten(treedef, leaves)
        g = nlp.constraints(x, pp, structure)
        return nlp.objective(x, pp, structure), jnp.concatenate(
            [jnp.ravel(a) for a in jax.tree.leaves(g)])

    example = [np.zeros(structure.n_x)] + [np.zeros(s, d) for s, d in leaf_specs]
    f, g = jaxpr_to_sx(fg, example, [x] + p_cols)
    return x, p, f, g


def _spec(params: NLPParams):
    leaves, treedef = jax.tree.flatten(params)
    return treedef, tuple((tuple(np.shape(a)), np.asarray(a).dtype) for a in leaves)


def casadi_functions(params: NLPParams, structure: NLPStructure) -> ca.Function:
    """A CasADi Function (x, p) -> (f, g) of this NLP shape; p = the flattened params
    (:func:`flat_params`)."""
    x, p, f, g = _problem(structure, *_spec(params))
    return ca.Function("fg", [x, p], [f, g])


def flat_params(params: NLPParams) -> np.ndarray:
    """One NLP's parameters as the vector p of :func:`casadi_functions` (its leaves in
    tree order, bools as 0 / 1)."""
    return _flat_params(params)


@functools.cache
def _solver(structure: NLPStructure, treedef, leaf_specs, codegen: bool, opts_key):
    x, p, f, g = _problem(structure, treedef, leaf_specs)
    opts = dict(opts_key)
    ipopt = {"tol": IPOPT_TOL, "constr_viol_tol": IPOPT_CONSTR_VIOL_TOL,
             "bound_relax_factor": 0.0, "print_level": 0, "sb": "yes",
             "max_iter": 3000, "hessian_approximation": "exact",
             "linear_solver": "mumps", **IPOPT_START}
    ipopt.update({k[len("ipopt."):]: v for k, v in opts.items() if k.startswith("ipopt.")})
    o = {"ipopt": ipopt, "print_time": False, "error_on_fail": False}
    if codegen:
        o.update({"jit": True, "compiler": "shell",
                  "jit_options": {"flags": ["-O1"], "verbose": False}})
    return ca.nlpsol("ipopt_ref", "ipopt", {"x": x, "p": p, "f": f, "g": g}, o)


class IpoptResult(NamedTuple):
    x: np.ndarray
    objective: float
    ineq_violation: float
    converged: bool  # IPOPT's return status Solve_Succeeded (or Solved_To_Acceptable_Level)
    return_status: str
    iterations: int
    wall_s: float  # the solve (one call of the nlpsol), its construction excluded
    evaluations: int  # calls of the constraint function (IPOPT's n_call_nlp_g)


def solve_ipopt(params: NLPParams, x0, structure: NLPStructure, *, codegen: bool = False,
                tau_max: float = np.log(1e3), options: dict | None = None) -> IpoptResult:
    """Solve one NLP (unbatched params) with IPOPT from x0.

    Bounds: log t_min <= tau <= log 1000 s (as :func:`jaxplan.reference.solve_slsqp`);
    g(x) >= 0.  Tolerances: IPOPT_TOL (IPOPT's scaled KKT error), IPOPT_CONSTR_VIOL_TOL
    (the constraint violation, jaxplan's default tol), bound_relax_factor 0 (the bound
    on T not relaxed); the start as IPOPT_START.  ``options``: further IPOPT options as
    {"ipopt.NAME": value}.
    The solver is built once per structure, parameter shapes and options (cached); its
    construction is not in wall_s.
    """
    flat = _flat_params(params)
    if not np.all(np.isfinite(flat)):
        raise ValueError("solve_ipopt: every NLPParams entry must be finite")
    key = tuple(sorted((options or {}).items()))
    S = _solver(structure, *_spec(params), codegen, key)
    n = structure.n_x
    lbx = np.full(n, -np.inf)
    ubx = np.full(n, np.inf)
    lbx[-1] = np.log(max(float(params.t_min), 1e-6))
    ubx[-1] = max(tau_max, lbx[-1] + 1.0)
    x0 = np.clip(np.asarray(x0, np.float64), lbx, ubx)
    t0 = time.perf_counter()
    r = S(x0=x0, p=flat, lbx=lbx, ubx=ubx, lbg=0.0, ubg=np.inf)
    wall = time.perf_counter() - t0
    st = S.stats()
    x = np.asarray(r["x"]).reshape(-1)
    g = np.asarray(r["g"]).reshape(-1)
    f = float(r["f"])
    viol = float(np.max(np.maximum(-g, 0.0), initial=0.0))
    ok = st["return_status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    return IpoptResult(x, f, viol, bool(ok and np.isfinite(f)), st["return_status"],
                       int(st.get("iter_count", -1)), wall,
                       int(st.get("n_call_nlp_g", 0) or 0))
