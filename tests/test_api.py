"""The documented top-level API (docs/DESIGN.md): jaxplan.predict, jaxplan.Trajectory,
jaxplan.run, and the packages' public surfaces."""

import subprocess
import sys


def test_top_level_names():
    import jaxplan
    import jaxplan.predict
    from jaxplan import Trajectory, predict
    from jaxplan.experiment import run
    from jaxplan.predict import predict_arrays

    assert jaxplan.predict.predict_arrays is predict_arrays  # the module's names
    traj = predict([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    ref = jaxplan.predict.predict([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
                                  [1.0, 0.0, 0.0])
    assert isinstance(traj, Trajectory) and float(traj.duration) == float(ref.duration)
    assert jaxplan.run is run


def test_importing_jaxplan_stays_light():
    code = ("import sys, jaxplan; heavy = [m for m in ('jaxplan.experiment', 'jaxplan.solve', "
            "'jaxplan.plots', 'jaxopt') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_public_surfaces():
    from jaxplan import files, metrics, nlp, solve

    for pkg in (nlp, solve, metrics, files):
        for name in pkg.__all__:
            assert getattr(pkg, name).__doc__ or not callable(getattr(pkg, name)), name
