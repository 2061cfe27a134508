"""Fault injection: the channel's statistics, latency, noise, a frozen robot, config errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.config import ConfigError, parse_config
from jaxplan.faults import FaultParams, initial_comm
from jaxplan.faults import communicate as _communicate

# one program per shape, as the planner runs it: op by op (eager) the tests' hundreds of
# periods took ~1.5-2.5 s each
communicate = jax.jit(_communicate)


def _channel(M=6, loss=0.0, noise=0.0, latency=0, frozen=None, frozen_at=0.0, stale=False):
    p = jnp.asarray(np.random.default_rng(0).normal(size=(M, 3)))
    g = p + 1.0
    rest = jnp.zeros(M, bool)
    comm = initial_comm(p, g, 0 * p, rest, latency, 7)
    fr = jnp.zeros(M, bool) if frozen is None else jnp.zeros(M, bool).at[frozen].set(True)
    f = FaultParams(jnp.asarray(loss), jnp.asarray(noise), fr, jnp.asarray(frozen_at),
                    jnp.asarray(stale), jnp.asarray(7, jnp.uint32))
    return p, g, rest, comm, f


def test_loss_rate_matches_probability():
    M = 6
    p, g, rest, comm, f = _channel(M, loss=0.2)
    lost = delivered = 0
    for k in range(200):
        comm, views, s = communicate(comm, f, 0.125 * k, p, 0 * p, 0 * p, g, 0 * p, rest)
        lost += int(s["lost"])
        delivered += int(s["delivered"])
    rate = lost / (lost + delivered)
    n = lost + delivered
    assert abs(rate - 0.2) < 4 * np.sqrt(0.2 * 0.8 / n)
    assert np.all(np.diag(np.asarray(views.age)) == 0)  # everyone knows itself


def test_latency_delivers_old_messages():
    M = 3
    p, g, rest, comm, f = _channel(M, latency=2)
    positions = []
    for k in range(6):
        pk = p + 0.1 * k
        comm, views, _ = communicate(comm, f, 0.125 * k, pk, 0 * p, 0 * p, g, 0 * p, rest)
        positions.append(np.asarray(pk))
    # observer 0 sees sender 1 as it was two periods ago, aged 0.25 s
    np.testing.assert_allclose(np.asarray(views.p[0, 1]), positions[3][1], atol=1e-12)
    assert abs(float(views.age[0, 1]) - 0.25) < 1e-12


def test_noise_is_per_observer_and_has_the_right_scale():
    M = 8
    p, g, rest, comm, f = _channel(M, noise=0.02)
    errs = []
    for k in range(50):
        comm, views, _ = communicate(comm, f, 0.125 * k, p, 0 * p, 0 * p, g, 0 * p, rest)
        e = np.asarray(views.p) - np.asarray(p)[None]
        errs.append(e[~np.eye(M, dtype=bool)])
        assert np.all(np.diagonal(e, axis1=0, axis2=1) == 0)
    errs = np.concatenate(errs)
    assert abs(errs.std() - 0.02) < 0.002
    assert not np.allclose(np.asarray(views.p[1, 0]), np.asarray(views.p[2, 0]))


@pytest.mark.parametrize("stale", [False, True])
def test_frozen_robot_silent_or_stale(stale):
    M = 3
    p, g, rest, comm, f = _channel(M, frozen=2, frozen_at=0.5, stale=stale)
    for k in range(12):
        pk = p + 0.1 * k
        comm, views, _ = communicate(comm, f, 0.125 * k, pk, 0 * p, 0 * p, g, 0 * p, rest)
    if stale:  # keeps sending its last pre-freeze message, freshly stamped
        assert float(views.age[0, 2]) == 0.0
        np.testing.assert_allclose(np.asarray(views.p[0, 2]), np.asarray(p[2] + 0.1 * 3))
    else:  # silent: the view ages
        assert float(views.age[0, 2]) > 0.8
    assert float(views.age[0, 1]) == 0.0


@pytest.mark.slow  # two closed loops with every fault on, their own program (~20 s): make test-slow
def test_run_with_faults_is_reproducible_and_finite(tmp_path):
    from jaxplan.experiment import run
    from tests.conftest import TINY_TOML

    text = TINY_TOML.replace("[sim]", "[faults]\nenabled = true\nmessage_loss = 0.3\n"
                             "noise_sigma_m = 0.02\nfrozen_robot = 2\nfrozen_at_s = 1.0\n[sim]")
    text = text.replace("duration_s = 12.0", "duration_s = 2.0")
    import tomllib

    cfg = parse_config(tomllib.loads(text), source="f.toml")
    r1, r2 = run(cfg), run(cfg)
    np.testing.assert_array_equal(r1.arrays["seg_coeffs"], r2.arrays["seg_coeffs"])
    assert np.all(np.isfinite(r1.arrays["pos"]))
    f = r1.metrics["faults"]
    assert f["messages_lost"] > 0 and f["frozen_robot"] == 2
    # the frozen robot brakes to rest within its a_max (no dead stop: its speed is
    # continuous at the freeze), then hovers where it stopped
    t = r1.arrays["t"]
    pos, vel, acc = (r1.arrays[k][2] for k in ("pos", "vel", "acc"))
    speed = np.linalg.norm(vel, axis=-1)
    k0 = int(np.searchsorted(t, 1.0))
    assert speed[k0 - 1] > 0.1, speed[k0 - 1]  # it was moving
    assert abs(speed[k0] - speed[k0 - 1]) < 0.05 * speed[k0 - 1] + 1e-3
    assert speed[k0:].max() <= 1.05 * speed[k0 - 1]  # braking (its acceleration fades)
    a_max = r1.metrics["per_robot"][2]["a_max"]
    assert np.linalg.norm(acc[k0:], axis=-1).max() <= 1.1 * a_max
    rest = t >= 1.0 + max(1.5 * speed[k0] / a_max, 0.5)
    assert np.ptp(pos[rest], axis=0).max() < 1e-9 and speed[rest].max() < 1e-9


@pytest.mark.parametrize("table, key", [
    ("message_loss = 1.0", "faults.message_loss"),
    ("message_loss = -0.1", "faults.message_loss"),
    ("latency_s = 'slow'", "faults.latency_s"),
    ("frozen_mode = 'sleepy'", "faults.frozen_mode"),
    ("noise_sigma_m = -1.0", "faults.noise_sigma_m"),
    ("frozen_robots = 1", "faults.frozen_robots"),
])
def test_fault_config_errors(table, key):
    import tomllib

    from tests.conftest import TINY_TOML

    text = TINY_TOML.replace("[sim]", f"[faults]\nenabled = true\n{table}\n[sim]")
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        parse_config(tomllib.loads(text), source="f.toml")


def test_frozen_robot_out_of_range():
    import tomllib

    from jaxplan.config import build_scenario
    from tests.conftest import TINY_TOML

    text = TINY_TOML.replace("[sim]", "[faults]\nenabled = true\nfrozen_robot = 3\n[sim]")
    cfg = parse_config(tomllib.loads(text), source="f.toml")
    with pytest.raises(ConfigError, match="faults.frozen_robot"):
        build_scenario(cfg)
