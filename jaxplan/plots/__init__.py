"""Figures and animations of a run directory and of a sweep directory (docs/DESIGN.md,
"A run directory", "A sweep directory"): drawing only.

    plot_run(run_dir, *, animation=True, mp4=False, max_frames=150) -> list[Path]
    plot_sweep(sweep_dir) -> list[Path]
    plot_tune(fig_dir, trials, importance, *, objective) -> list[Path]

Modules: :mod:`~jaxplan.plots.run` (the static run figures),
:mod:`~jaxplan.plots.animation`, :mod:`~jaxplan.plots.sweep` (the heatmaps),
:mod:`~jaxplan.plots.scene` (the world: obstacles, faces, clearances),
:mod:`~jaxplan.plots.tune` (a tune directory's objective, importance, Pareto front),
:mod:`~jaxplan.plots.style` (sizes, style, colours, saving).  The data come from
:func:`jaxplan.files.load_run` (a run directory, validated) and
:mod:`jaxplan.sweep.table` (sweep.csv, its grid and best setting); the animation's frames
are encoded by :mod:`jaxplan.files.media`; every file is written atomically
(:mod:`jaxplan.files.durable`).  Everything is drawn on :class:`matplotlib.figure.Figure`
objects with the Agg canvas; pyplot is never imported, the global backend is never
switched, and the style is applied inside ``matplotlib.rc_context`` only, so importing
or calling this module leaves no global matplotlib state behind.

Run figures (``run_dir/figures/``), sizes in pixels:

    trajectories_3d.png  840 x 720   paths in 3-D (equal aspect), starts o, goals ^,
                                     waypoints x, the world's obstacles and finite
                                     workspace faces (:mod:`~jaxplan.plots.scene`);
                                     ``trajectories_2d.png`` for planar (N=2)
    trajectories_top.png 840 x 720   (N=3 only) the x-y view: paths, obstacle
                                     footprints, the finite x and y faces
    speed_acc.png        960 x 660   |v| and |a| over time per robot, dotted limit lines
    separation.png      1320 x 576   d_ij(t) / rho_ij for every pair, the line at 1, each
                                     pair's minimum, the worst pair highlighted; and the
                                     M x M matrix of per-pair minimum ratios
    clearance.png       1320 x 576   each robot's clearance over time (signed distance -
                                     radius, from the samples): min over the obstacles,
                                     and beside it min over the finite workspace faces;
                                     the line at 0, the worst instant marked (a note
                                     when the world is empty and unbounded)
    animation.gif        640 x 480   the fleet moving in its world (<= max_frames
                                     frames, ~16.7 fps), markers scaled to the
                                     collision radius, 2 s trails;
                                     ``animation.mp4`` instead when mp4=True and ffmpeg
                                     is on PATH

Sweep figures (``sweep_dir/figures/``): ``success_rate.png``, ``min_separation.png``,
``makespan.png``; one panel per scenario group ("all scenarios", then each scenario when
there are several), 460 x 400 pixels per panel; the best setting
(:func:`jaxplan.sweep.table.best_setting`) is outlined on every panel.

Bad input (a missing file or key, a wrong shape, non-finite numbers, an unreadable CSV
cell) raises ``ValueError("<file>: <key>: <problem>")`` before anything is drawn.
"""

from __future__ import annotations

from jaxplan.plots.run import plot_run
from jaxplan.plots.style import robot_colors
from jaxplan.plots.sweep import plot_sweep
from jaxplan.plots.tune import plot_tune

__all__ = ["plot_run", "plot_sweep", "plot_tune", "robot_colors"]
