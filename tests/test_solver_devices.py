"""Tests of jaxplan.solve on CPU devices and threads: a batch split over devices, and
LAPACK calls that never split their batch (the deadlock they once caused).  Split from
test_solver.py so that the two test workers share the solver's tests evenly."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxplan
from jaxplan import solve
from tests.test_solver import S1, S2, B, _s1_batch

_SPLIT = """
import jax, numpy as np
import jaxplan
from jaxplan import solve
from jaxplan.testing import random_problem, stack_params
from jaxplan.nlp import NLPStructure
assert len(jax.devices("cpu")) == 2
L = solve.LOCKSTEP_MAX
assert solve.default_shards(L + 1, "cpu") == 2 and solve.default_shards(L, "cpu") == 1
assert solve.default_shards(640, "gpu") == 1
rng = np.random.default_rng(7)  # _problems(7): >= 90% converge
n = 49  # odd: padded for the split, the copy dropped
P = stack_params([random_problem(rng, n_others=int(rng.integers(2, 11)), rest=bool(i % 2))
                  for i in range(n)])
st = NLPStructure(collision="barrier+constraint")
x0 = solve.initial_guess_batch(P, st)
one = jax.device_get(solve.solve_batch(P, x0, st, shards=1))
split = jax.device_get(solve.solve_batch(P, x0, st))
np.testing.assert_array_equal(split.status, one.status)
np.testing.assert_array_equal(split.iterations, one.iterations)
conv = one.status == solve.CONVERGED
assert conv.sum() >= 0.9 * n
for a, b in zip(jax.tree.leaves(split), jax.tree.leaves(one), strict=True):
    assert np.asarray(a).shape == np.asarray(b).shape
    np.testing.assert_allclose(np.asarray(a)[conv], np.asarray(b)[conv], rtol=1e-9, atol=1e-9)
try:
    solve.solve_batch(P, x0, st, shards=3)
    raise SystemExit("shards = 3 accepted")
except ValueError as e:
    assert "shards = 3" in str(e)
# a cold start (x0 = None): each device forms its own lanes' guesses in the solve's program
cold = jax.device_get(solve.solve_batch(P, None, st))
np.testing.assert_array_equal(cold.iterations, split.iterations)
np.testing.assert_allclose(cold.x[conv], split.x[conv], rtol=1e-9, atol=1e-9)
# the lanes are dealt round-robin (device d: lanes d, d + 2, ...) and come back in order
import jax.numpy as jnp
deal = jax.jit(lambda a: solve.shard_lanes(
    lambda b: (b, jnp.full(b.shape, jax.lax.axis_index("lanes"))), (a,), 2))
back, dev = jax.device_get(deal(jnp.arange(7.0)))
np.testing.assert_array_equal(back, np.arange(7.0))
np.testing.assert_array_equal(dev, np.arange(7) % 2)
print("ok")
"""


@pytest.mark.slow  # a child compiling four solver programs on two devices (~19 s of the suite)
def test_batch_split_over_cpu_devices_gives_the_one_device_results(tmp_path):
    """solve_batch splits a batch of more than LOCKSTEP_MAX NLPs over the CPU devices
    (jaxplan makes one per core; solve.default_shards), here in a child process with
    JAXPLAN_CPU_DEVICES=2 (the suite's own processes keep one: conftest): every lane
    takes the same iterations and ends with the same status as on one device, and the
    same floats to rounding where it converged; so does a cold start (x0 = None: the
    guesses formed per device in the solve's program).  The batch is odd: padded, and
    the copies dropped.  The lanes are dealt to the devices round-robin."""
    import subprocess
    import sys

    from tests._proc import ROOT, child_env

    env = child_env(tmp_path / "cache", JAXPLAN_CPU_DEVICES="2")
    r = subprocess.run([sys.executable, "-c", _SPLIT], env=env, cwd=ROOT,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-3000:]


def test_packed_arguments_come_back_exactly():
    """solve_batch hands a program split over devices its arguments as a few host
    arrays (solve.batch.pack_leaves; the small leaves packed end to end per dtype, the
    large ones as they are): unpacked, inside a jitted program as outside, every leaf
    comes back with its shape, dtype and bits (NaN, -0.0, the extremes of int32 and
    int64 values float64 cannot hold included), and None stays None."""
    from jaxplan.solve.batch import PACK_ALONE_BYTES, pack_leaves, unpack_leaves

    rng = np.random.default_rng(3)
    odd = np.array([np.nan, -0.0, np.inf, -np.inf, 5e-324, 1.7976931348623157e308])
    tree = dict(a=rng.normal(size=(4, 3)), odd=odd,
                n=jnp.asarray([-2**31, 2**31 - 1, 0], jnp.int32),
                k=np.array([-2**62, 2**53 + 1], np.int64),
                b=np.array([True, False, True]), s=np.float64(0.25), i=np.int32(7),
                empty=np.zeros((4, 2, 0)), none=None,
                big=rng.normal(size=(PACK_ALONE_BYTES // 8 + 5,)),
                big_b=np.ones((PACK_ALONE_BYTES + 1,), bool), nested=(jnp.arange(5.0), None))
    arrays, layout = pack_leaves(tree)
    assert len(arrays) == 4 + 2  # f64, i64, i32, bool packed; the two large leaves alone
    assert all(isinstance(a, np.ndarray) for a in arrays)
    hash(layout)  # a static argument of the jitted program
    for back in (unpack_leaves(arrays, layout),
                 jax.jit(unpack_leaves, static_argnums=1)(arrays, layout)):
        assert jax.tree.structure(back) == jax.tree.structure(tree)
        for x, y in zip(jax.tree.leaves(tree), jax.tree.leaves(back), strict=True):
            x, y = np.asarray(x), np.asarray(y)
            assert x.shape == y.shape and x.dtype == y.dtype
            assert x.tobytes() == y.tobytes()


def test_cpu_device_count_from_the_environment(monkeypatch):
    """JAXPLAN_CPU_DEVICES sets the CPU device count jaxplan asks JAX for; a bad value
    fails with a message that names the variable."""
    monkeypatch.setenv(jaxplan.CPU_DEVICES_ENV, "3")
    assert jaxplan._cpu_device_count() == 3
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv(jaxplan.CPU_DEVICES_ENV, bad)
        with pytest.raises(ValueError, match=jaxplan.CPU_DEVICES_ENV):
            jaxplan._cpu_device_count()


def _lapack_batches(lowered, kernels=("lapack_dsyevd",)):
    """(matrices, n) of every call of the LAPACK ``kernels`` in a lowered program, all
    leading batch axes counted."""
    import re
    out = []
    for ln in lowered.as_text().splitlines():
        if any(k in ln for k in kernels):
            dims = [int(v) for v in re.search(r": \(tensor<([\dx]+)xf64>", ln).group(1).split("x")]
            out.append((math.prod(dims[:-2]), dims[-1]))
    return out


def test_lapack_constants_are_those_of_the_installed_jaxlib():
    """solve.linalg's LAPACK_SPLIT_COST and EIGH_COST are copied from jaxlib's C++
    (jaxlib/cpu/lapack_kernels.cc); a different jaxlib may have changed them."""
    import jaxlib

    pinned = solve.linalg.LAPACK_JAXLIB_VERSION
    assert jaxlib.__version__ == pinned, (
        f"jaxlib {jaxlib.__version__} is installed, but jaxplan/solve/linalg.py copied "
        f"LAPACK_SPLIT_COST and EIGH_COST from jaxlib {pinned}: re-read kMinWorkPerTask and "
        "eigh's cost_per_matrix in jaxlib/cpu/lapack_kernels.cc of the new version, update "
        "them and LAPACK_JAXLIB_VERSION (and pyproject.toml's pin)")


def test_cpu_eigh_calls_never_split_their_batch():
    """jaxlib 0.10's batched LAPACK kernels (eigh; Cholesky alike) split a batch of more
    than one matrix costing batch x 5 n^3 >= 2e5 over XLA's CPU thread pool and block a
    pool thread while they wait; two such solves at once deadlock (solve.linalg.lapack_safe).
    So every such call the solver compiles for the CPU stays below that, and the chunked
    eigh returns what one batched call returns."""
    # a call of one matrix never splits, whatever its size
    ok = lambda b, n: b == 1 or b * solve.linalg.EIGH_COST * n ** 3 < solve.linalg.LAPACK_SPLIT_COST
    rng = np.random.default_rng(3)
    for n in (7, 19, 37):
        k = solve.eigh_chunk(n)
        assert ok(k, n) and (k == 1 or not ok(k + 1, n))
        for batch in (1, k, k + 1, 3 * k + 2, (solve.linalg.UNROLL_EIGH + 2) * k - 1):
            A = rng.normal(size=(batch, n, n))
            H = A + A.transpose(0, 2, 1)
            f = jax.jit(jax.vmap(solve.linalg.eigh_safe))
            sizes = _lapack_batches(f.lower(H))
            assert sizes and all(m == n and ok(b, n) for b, m in sizes), (n, batch, sizes)
            w, V = f(H)
            w0, V0 = jnp.linalg.eigh(H)
            np.testing.assert_array_equal(w, w0)
            np.testing.assert_array_equal(V, V0)
    # the solver's own programs: a lockstep batch of two-segment NLPs and a pooled one
    for st, n_lanes in ((S2["barrier"], 10), (S2["barrier"], B), (S1, B)):
        _, P = _s1_batch()
        sub = jax.tree.map(lambda a, n=n_lanes: a[:n], P)
        x0 = jnp.zeros((n_lanes, st.n_x))
        lowered = solve.batch._solve_batch_jit.lower(
            solve.as_strong_dtypes(sub), x0, st, solve.as_strong_dtypes(solve.SolverSettings()),
            None, None,
            pool=solve.default_pool(n_lanes, n_others=P.other_mask.shape[-1]))
        sizes = _lapack_batches(lowered)
        assert sizes and all(m == st.n_x and ok(b, m) for b, m in sizes), (st, sizes)
        if n_lanes == 10 and st.segments == 2:  # as one call this batch would split
            assert not ok(n_lanes, st.n_x)
        # the Cholesky steps' LAPACK calls (potrf, trsm) split their batches alike, and
        # the same bound keeps them whole (their kernels are cheaper than syevd's)
        chol = _lapack_batches(lowered, ("lapack_dpotrf", "lapack_dtrsm"))
        assert chol and all(m == st.n_x and ok(b, m) for b, m in chol), (st, chol)


def test_nested_vmaps_of_the_solver_never_split_a_lapack_batch():
    """jax.vmap of solve (whose steps vmap over a batch of one lane) is a vmap of a
    vmap: the outer level must chunk its LAPACK calls as well (solve.linalg.lapack_safe's
    ``per``).  Before, it batched the inner call whole, and a vmapped solve of the
    bench's 640 NLPs hung at 0% CPU.  The chunked nested eigh equals one batched call."""
    ok = lambda b, n: b == 1 or b * solve.linalg.EIGH_COST * n ** 3 < solve.linalg.LAPACK_SPLIT_COST
    rng = np.random.default_rng(4)
    n = 19
    k = solve.eigh_chunk(n)
    for shape in ((3 * k + 2, 1), (k + 1, 2), ((solve.linalg.UNROLL_EIGH + 2) * k, 3)):
        A = rng.normal(size=shape + (n, n))
        H = A + np.swapaxes(A, -1, -2)
        f = jax.jit(jax.vmap(jax.vmap(solve.linalg.eigh_safe)))
        sizes = _lapack_batches(f.lower(H), ("lapack_dsyevd",))
        assert sizes and all(m == n and ok(b, n) for b, m in sizes), (shape, sizes)
        w, V = f(H)
        w0, V0 = jnp.linalg.eigh(H)
        np.testing.assert_array_equal(w, w0)
        np.testing.assert_array_equal(V, V0)
    # the public route: jax.vmap(solve) over more lanes than one call may hold
    st = S2["barrier+constraint"]
    _, P = _s1_batch()
    assert not ok(B, st.n_x)
    lowered = jax.jit(jax.vmap(lambda p, x: solve.solve(p, x, st))).lower(
        solve.as_strong_dtypes(P), jnp.zeros((B, st.n_x)))
    for kernels in (("lapack_dsyevd",), ("lapack_dpotrf", "lapack_dtrsm")):
        sizes = _lapack_batches(lowered, kernels)
        assert sizes and all(m == st.n_x and ok(b, m) for b, m in sizes), (kernels, sizes)


_THREADS = """
import threading, numpy as np, jax
import jaxplan
from jaxplan import solve
from jaxplan.testing import random_problem, stack_params
from jaxplan.nlp import NLPStructure
rng = np.random.default_rng(7)
P = stack_params([random_problem(rng, n_others=int(rng.integers(2, 11)), rest=bool(i % 2))
                  for i in range(40)])
st = NLPStructure(collision="barrier+constraint", segments=2)
x0 = np.asarray(solve.initial_guess_batch(P, st))
half = [(jax.tree.map(lambda a: a[i:i + 20], P), x0[i:i + 20]) for i in (0, 20)]
one = [np.asarray(solve.solve_batch(p, x, st).x) for p, x in half]
for _ in range(3):
    out = [None, None]
    def work(j):
        out[j] = np.asarray(solve.solve_batch(*half[j], st).x)
    ts = [threading.Thread(target=work, args=(j,)) for j in (0, 1)]
    [t.start() for t in ts]
    [t.join() for t in ts]
    assert all(np.array_equal(a, b) for a, b in zip(out, one))
print("ok")
"""


@pytest.mark.slow  # a child process, ~11 s: `make test-slow`
def test_two_threads_solving_at_once_do_not_deadlock(tmp_path):
    """Two Python threads each solve a batch of two-segment NLPs at the same time (in a
    child process, under a time limit): before solve.linalg.eigh_safe this hung at 0% CPU in 6
    of 7 tries (the LAPACK batch split above).  Same results as one at a time.  The cause
    is checked in the default suite without threads (test_cpu_eigh_calls_never_split_
    their_batch, test_nested_vmaps_of_the_solver_never_split_a_lapack_batch)."""
    import subprocess
    import sys

    from tests._proc import ROOT, child_env

    r = subprocess.run([sys.executable, "-c", _THREADS], env=child_env(tmp_path / "cache"),
                       cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-3000:]


def test_collective_timeouts_are_set_and_a_users_value_is_kept(monkeypatch):
    """Importing jaxplan lets the CPU devices of a split batch wait for each other up to
    an hour (XLA's 40 s default aborted a sweep on a loaded machine); a value already in
    XLA_FLAGS is kept."""
    import os

    assert "--xla_cpu_collective_call_terminate_timeout_seconds=3600" in os.environ["XLA_FLAGS"]
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_collective_call_terminate_timeout_seconds=7")
    jaxplan._set_collective_timeouts()
    flags = os.environ["XLA_FLAGS"].split()
    assert "--xla_cpu_collective_call_terminate_timeout_seconds=7" in flags
    assert not any(f.endswith("terminate_timeout_seconds=3600") for f in flags)
    assert "--xla_cpu_collective_call_warn_stuck_timeout_seconds=300" in flags


def test_collective_timeouts_go_before_a_word_xla_would_stop_at(monkeypatch, tmp_path):
    """XLA parses XLA_FLAGS up to the first word that is not a --flag and drops the rest
    without a word: jaxplan's flags go first, so that they still reach XLA (a child
    process dumps its HLO only if a flag placed as jaxplan places its own is read); a
    value that names a file of flags is left alone."""
    import os
    import subprocess
    import sys

    from tests._proc import ROOT, child_env

    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false stray_word=1")
    jaxplan._set_collective_timeouts()
    flags = os.environ["XLA_FLAGS"].split()
    assert flags.index("stray_word=1") > max(
        i for i, f in enumerate(flags) if "collective_call" in f)
    monkeypatch.setenv("XLA_FLAGS", "flags.txt")
    jaxplan._set_collective_timeouts()
    assert os.environ["XLA_FLAGS"] == "flags.txt"
    # the parsing itself: a flag after the stray word is lost, one before it is read
    code = "import jax, jax.numpy as jnp; jax.jit(lambda a: a + 1)(jnp.ones(2)).block_until_ready()"
    for where, dumped in (("before", True), ("after", False)):
        dump = tmp_path / where
        f = f"--xla_dump_to={dump}"
        # (a value that starts with a non-flag word would be read as a file name)
        env = child_env(tmp_path / f"cache_{where}") | {  # no program from a cache
            "XLA_FLAGS": f"{f} stray_word=1" if where == "before"
            else f"--xla_cpu_multi_thread_eigen=false stray_word=1 {f}"}
        r = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT,
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr[-2000:]
        assert dump.exists() == dumped, where


_LAG = """
import time
import jaxplan
import jax, jax.numpy as jnp
from jax.sharding import Mesh, PartitionSpec as P
mesh = Mesh(jax.devices("cpu")[:2], ("d",))
def lag(i):
    if int(i) == 0:
        time.sleep(45.0)  # past XLA's default 40 s termination timeout
    return i
def f(x):
    i = jax.lax.axis_index("d").astype(jnp.int32)
    y = jax.pure_callback(lag, jax.ShapeDtypeStruct((), jnp.int32), i)
    return jax.lax.all_gather(x + y, "d")
g = jax.jit(jax.shard_map(f, mesh=mesh, in_specs=P("d"), out_specs=P(), check_vma=False))
print(list(map(float, g(jnp.arange(2.0)).ravel())))
"""


@pytest.mark.slow  # waits 45 s by design: `make test-slow`
def test_a_device_45_s_late_to_an_all_gather_does_not_abort(tmp_path):
    """One device reaches the all-gather 45 s after the other (a loaded machine): the
    program completes instead of XLA's abort at 40 s."""
    import subprocess
    import sys

    from tests._proc import ROOT, child_env

    env = child_env(tmp_path / "cache", JAXPLAN_CPU_DEVICES="2")
    env.pop("XLA_FLAGS", None)
    r = subprocess.run([sys.executable, "-c", _LAG], env=env, cwd=ROOT, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.strip() == "[0.0, 2.0]"
