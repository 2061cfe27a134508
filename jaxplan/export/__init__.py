"""A run exported for hardware and for the robotics tools (`jaxplan export`,
docs/HARDWARE.md).

Modules:

    common.py       ExportError, the run read back complete, each robot's limits
    crazyswarm.py   Crazyswarm ``uav_trajectory`` CSVs: each robot's executed pieces
                    refitted as at most 31 C2 pieces of degree 7 within 1 cm
    mcap.py         an MCAP file (JSON messages under Foxglove's schemas): poses,
                    velocities, goals, the world (a moving obstacle
                    at every sample) and the metrics

    export_run(run_dir, fmt, out_dir=None, height=None) -> report (a dict)

The ``mcap`` format needs the ``mcap`` package (``pip install -e ".[export]"``).
"""

from __future__ import annotations

from jaxplan.export.common import ExportError

__all__ = ["FORMATS", "ExportError", "export_run"]

FORMATS = ("crazyswarm", "mcap")


def export_run(run_dir, fmt: str, out_dir=None, height: float | None = None,
               progress=None) -> dict:
    """Export the run in ``run_dir`` as ``fmt`` (one of :data:`FORMATS`) into
    ``out_dir`` (default: ``run_dir/crazyswarm`` for CSVs, ``run_dir`` for the MCAP
    file); returns the format's report (:func:`jaxplan.export.crazyswarm.export_crazyswarm`,
    :func:`jaxplan.export.mcap.export_mcap`).  height: m, a planar run's flight height
    (crazyswarm only).  Raises ExportError."""
    if fmt == "crazyswarm":
        from jaxplan.export.crazyswarm import export_crazyswarm

        return export_crazyswarm(run_dir, out_dir, height=height, progress=progress)
    if fmt == "mcap":
        if height is not None:
            raise ExportError("--height: only for --format crazyswarm (an MCAP file keeps a "
                              "planar run in z = 0)")
        try:
            import mcap  # noqa: F401
        except ImportError:
            raise ExportError('--format mcap needs the mcap package: pip install -e '
                              '".[export]"') from None
        from jaxplan.export.mcap import export_mcap

        return export_mcap(run_dir, out_dir)
    raise ExportError(f"--format {fmt!r}: one of {', '.join(FORMATS)}")
