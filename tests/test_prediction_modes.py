"""Ablations of the paper's prediction ([planner] prediction, jaxplan/planner/views.py):
"constant_velocity" and "static" are exactly a straight line and a held position
(against numpy), and `jaxplan run` flies each of them, differently from the default."""

from __future__ import annotations

import json
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.cli import main
from jaxplan.config import ConfigError, parse_config
from jaxplan.planner import PREDICTIONS, Views, predict_views
from jaxplan.run_setup import structures
from tests.conftest import TINY_TOML

_predict = jax.jit(predict_views, static_argnums=2)


def _views(rng, M=4, N=3):
    p = rng.normal(size=(M, M, N)) * 3
    v = rng.normal(size=(M, M, N))
    a = rng.normal(size=(M, M, N))
    g = rng.normal(size=(M, M, N)) * 3
    return Views(jnp.asarray(p), jnp.asarray(v), jnp.asarray(a), jnp.asarray(g),
                 jnp.zeros((M, M, N)), jnp.zeros((M, M), bool), jnp.zeros((M, M)),
                 jnp.ones((M, M), bool))


@pytest.mark.parametrize("mode", ["constant_velocity", "static"])
def test_the_ablations_are_a_straight_line_and_a_hold(rng, mode):
    views = _views(rng)
    closed = _predict(views, 1.0, "min_time_jerk")
    tr = _predict(views, 1.0, mode)
    # the closed form's shape and degree: the NLP and everything downstream unchanged
    assert tr.coeffs.shape == closed.coeffs.shape and tr.breaks.shape == closed.breaks.shape
    p, v = np.asarray(views.p), np.asarray(views.v)
    for t in (0.0, 0.125, 0.7, 3.0, 40.0):
        want = p + v * t if mode == "constant_velocity" else p
        np.testing.assert_allclose(np.asarray(tr.evaluate(t)), want, rtol=1e-15, atol=1e-15)
        np.testing.assert_allclose(np.asarray(tr.evaluate(t, 1)),
                                   v if mode == "constant_velocity" else 0.0 * v, rtol=0,
                                   atol=0)
        np.testing.assert_array_equal(np.asarray(tr.evaluate(t, 2)), 0.0)
    # a message's age shifts it exactly as it would the closed form
    np.testing.assert_allclose(np.asarray(tr.shift(0.5).evaluate(1.0)),
                               np.asarray(tr.evaluate(1.5)), rtol=1e-14, atol=1e-14)


def test_a_non_finite_view_becomes_a_hold(rng):
    views = _views(rng)
    views = views._replace(v=views.v.at[0, 1, 0].set(jnp.nan),
                           p=views.p.at[1, 2, 1].set(jnp.inf))
    for mode in PREDICTIONS:
        tr = _predict(views, 1.0, mode)
        assert np.all(np.isfinite(np.asarray(tr.evaluate(2.0))))


def test_the_config_key_sets_the_structure_and_checks_its_value():
    data = tomllib.loads(TINY_TOML)
    assert structures(parse_config(data)).planner.prediction == "min_time_jerk"
    data["planner"] = {"prediction": "static"}
    assert structures(parse_config(data)).planner.prediction == "static"
    data["planner"] = {"prediction": "ballistic"}
    with pytest.raises(ConfigError, match="planner.prediction: unknown value 'ballistic'; "
                                          "choose one of 'min_time_jerk'"):
        parse_config(data)


def _run(tmp_path, mode):
    text = TINY_TOML.replace("[sim]\nduration_s = 12.0", "[sim]\nduration_s = 4.0")
    if mode is not None:
        text += f'\n[planner]\nprediction = "{mode}"\n'
    cfg = tmp_path / f"{mode}.toml"
    cfg.write_text(text)
    out = tmp_path / f"run_{mode}"
    assert main(["run", str(cfg), "--out", str(out), "--quiet", "--no-figures"]) == 0
    z = np.load(out / "trajectories.npz", allow_pickle=False)
    return json.loads((out / "metrics.json").read_text()), z["pos"]


@pytest.mark.slow  # each ablation is a program of its own (a compile each)
def test_each_prediction_runs_through_jaxplan_run_and_differs(tmp_path):
    _, default = _run(tmp_path, None)
    for mode in ("constant_velocity", "static"):
        m, pos = _run(tmp_path, mode)
        assert m["robots"] == 3 and m["replans"] == 32
        assert np.all(np.isfinite(pos))
        assert pos.shape == default.shape and not np.array_equal(pos, default), mode
