"""The animation of a run directory: the fleet moving, markers scaled to the collision
radius, with trails, and the moving obstacles where they are at each frame's time (their
paths dotted in the still scene); frames drawn here, encoded by
:mod:`jaxplan.files.media`."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.collections import LineCollection

from jaxplan.files import RunData, media
from jaxplan.plots.scene import (
    OBSTACLE_EDGE,
    OBSTACLE_FACE,
    draw_world_2d,
    draw_world_3d,
    moving_outlines,
)
from jaxplan.plots.style import (
    ANIM_DPI,
    FIGSIZE,
    STYLE,
    apply_bounds,
    bounds,
    new_figure,
    robot_colors,
)

FRAME_MS = 60  # GIF frame delay (a multiple of 10 ms, ~16.7 fps)
TRAIL_S = 2.0  # s of trail behind each robot in the animation


def frame_times(t, max_frames):
    dur = float(t[-1] - t[0])
    realtime = int(math.ceil(dur * 1000.0 / FRAME_MS)) + 1
    nf = max(2, min(int(max_frames), realtime))
    return np.linspace(t[0], t[-1], nf)


def _interp(t, x, tf):
    """x (M, K, N) sampled at t (K,) -> (M, F, N) at tf (F,), linear."""
    m, _, n = x.shape
    out = np.empty((m, tf.size, n))
    for i in range(m):
        for d in range(n):
            out[i, :, d] = np.interp(tf, t, x[i, :, d])
    return out


def _to_pixels(ax, pts):
    """Positions pts (..., N) m -> display pixels (..., 2) and depth (...,) (larger is
    farther; zeros in 2-D), for an axes whose view is fixed (after a draw)."""
    flat = pts.reshape(-1, pts.shape[-1])
    if pts.shape[-1] == 3:
        from mpl_toolkits.mplot3d import proj3d

        x, y, z = proj3d.proj_transform(flat[:, 0], flat[:, 1], flat[:, 2], ax.M)
        xy, depth = np.column_stack([x, y]), np.asarray(z)
    else:
        xy, depth = flat, np.zeros(flat.shape[0])
    px = ax.transData.transform(xy)
    return px.reshape(pts.shape[:-1] + (2,)), depth.reshape(pts.shape[:-1])


def _px_per_m(ax, lim):
    """Pixels per metre of an equal-aspect axes (orthographic in 3-D), after a draw: the
    largest singular value of the projection of the unit axes."""
    c = lim.mean(axis=1)
    step = 0.25 * float((lim[:, 1] - lim[:, 0]).min())
    pts = np.vstack([c, c + step * np.eye(c.size)])
    px, _ = _to_pixels(ax, pts)
    jac = (px[1:] - px[0]).T / step  # (2, N)
    return float(np.linalg.svd(jac, compute_uv=False)[0])


def animate(data: RunData, out: Path, *, mp4: bool, max_frames: int) -> Path:
    """Render the animation.  The static scene (axes, the world without its moving
    obstacles' bodies, faint full paths, goals) is drawn once; every frame restores it
    and draws four artists on top: the moving obstacles (one PolyCollection of their
    outlines, where they are at the frame's time), the trails (one LineCollection), the
    bodies (one EllipseCollection, discs of the collision radius, back to front) and
    the clock.  Positions are projected to pixels once, up front (orthographic 3-D
    view, equal aspect), so that a frame costs only its four artists."""
    if int(max_frames) < 2:
        raise ValueError(f"max_frames must be >= 2; got {max_frames}")
    use_mp4 = _use_mp4(mp4)
    cols = np.asarray(robot_colors(data.num_robots))
    lim = bounds(data)
    tf = frame_times(data.t, max_frames)
    with matplotlib.rc_context(STYLE):
        fig, ax = _static_scene(data, cols, lim)
        frames = _frames(data, fig, ax, cols, lim, tf)
        size = fig.canvas.get_width_height()
        if use_mp4:
            return media.write_mp4(frames, size, out / "animation.mp4", FRAME_MS)
        return media.write_gif(frames, out / "animation.gif", FRAME_MS)


def _use_mp4(mp4: bool) -> bool:
    """Whether to write MP4: asked for and ffmpeg on PATH (a warning when it is not)."""
    if mp4 and not media.ffmpeg_available():
        warnings.warn("ffmpeg not found on PATH: writing animation.gif instead of .mp4",
                      stacklevel=4)
        return False
    return mp4


def _static_scene(data: RunData, cols, lim):
    """(figure, axes) with what every frame shares: the axes, the world (obstacles and
    workspace faces, :mod:`jaxplan.plots.scene`), faint full paths, goals and the
    title."""
    m, n = data.num_robots, data.ndim
    fig = new_figure(FIGSIZE["animation"], dpi=ANIM_DPI, layout=None)
    fig.subplots_adjust(left=0.02 if n == 3 else 0.12, right=0.98,
                        bottom=0.08 if n == 3 else 0.11, top=0.92)
    ax = fig.add_subplot(projection="3d" if n == 3 else None)
    apply_bounds(ax, lim, n)
    span = (data.t[0], data.t[-1])  # moving obstacles: their paths; bodies per frame
    if n == 3:
        ax.set_proj_type("ortho")
        ax.view_init(elev=25, azim=-60)
        draw_world_3d(ax, data.world, lim, span, moving=False)
    else:
        draw_world_2d(ax, data.world, lim, span, moving=False)
    for i in range(m):
        ax.plot(*data.pos[i].T, color=cols[i], lw=0.8, alpha=0.2)
        ax.plot(*data.goal[i][:, None], ls="", marker="^", ms=6, color=cols[i], mec="k",
                mew=0.5, alpha=0.8)
    fig.text(0.97, 0.95, f"{data.name}: {m} robot{'s' if m != 1 else ''}", fontsize=9,
             ha="right", va="top")
    return fig, ax


def _frames(data: RunData, fig, ax, cols, lim, tf, artists=None):
    """Draw the static scene once, add the animated artists, and return a generator of
    the frames at times tf, each a fresh (H, W, 4) uint8 RGBA array.  ``artists``: a
    dict that receives the animated artists by name ("obstacles", "trails", "bodies",
    "label"; for inspection) and "obstacle_index" (the moving obstacles in the order of
    the obstacle collection's offsets)."""
    from matplotlib.collections import EllipseCollection, PolyCollection
    from matplotlib.transforms import IdentityTransform

    m = data.num_robots
    pf = _interp(data.t, data.pos, tf)  # (M, F, N)
    canvas = fig.canvas
    canvas.draw()  # fixes the layout and the view: from here on, project once
    background = canvas.copy_from_bbox(fig.bbox)
    pix, _ = _to_pixels(ax, data.pos)  # (M, K, 2)
    fpix, fdepth = _to_pixels(ax, pf)  # (M, F, 2), (M, F)
    diam = 2.0 * data.radius * _px_per_m(ax, lim)  # (M,) pixels
    ident = IdentityTransform()
    trails = LineCollection([], colors=cols, linewidths=1.8, transform=ident, animated=True)
    bodies = EllipseCollection(diam, diam, np.zeros(m), units="dots", offsets=fpix[:, 0],
                               offset_transform=ident, facecolors=cols, edgecolors="k",
                               linewidths=0.5, alpha=0.85, animated=True)
    # the moving obstacles: outlines in pixels about their centres' projections (affine
    # views), moved per frame to where each centre is at the frame's time
    project = lambda pts: _to_pixels(ax, pts)[0]
    outlines = moving_outlines(data.world, project, (data.t[0], data.t[-1]))
    ks = list(outlines)
    opix = (project(data.world.center_at(tf)[0][:, ks]) if ks
            else np.zeros((tf.size, 0, 2)))  # (F, J, 2)
    obstacles = PolyCollection([outlines[k] for k in ks], offsets=opix[0],
                               offset_transform=ident, transform=ident,
                               facecolors=OBSTACLE_FACE, edgecolors=OBSTACLE_EDGE,
                               linewidths=0.8, alpha=0.6, animated=True)
    for art in (obstacles, trails, bodies):
        fig.add_artist(art)
    label = fig.text(0.03, 0.95, "", fontsize=11, family="monospace", va="top", animated=True)
    bbox = ax.get_window_extent()
    for art in (obstacles, trails, bodies):
        art.set_clip_box(bbox)
    if artists is not None:
        artists.update(obstacles=obstacles, trails=trails, bodies=bodies, label=label,
                       obstacle_index=ks)

    def frames():
        for f, tt in enumerate(tf):
            hi = int(np.searchsorted(data.t, tt, side="right"))
            lo = int(np.searchsorted(data.t, tt - TRAIL_S, side="left"))
            canvas.restore_region(background)
            if ks:  # behind the robots: a robot is never hidden
                obstacles.set_offsets(opix[f])
                fig.draw_artist(obstacles)
            trails.set_segments(
                [np.concatenate([pix[i, lo:hi], fpix[i, f][None]]) for i in range(m)])
            order = np.argsort(-fdepth[:, f], kind="stable")  # far to near
            bodies.set_offsets(fpix[order, f])
            bodies.set_widths(diam[order])
            bodies.set_heights(diam[order])
            bodies.set_facecolor(cols[order])
            fig.draw_artist(trails)
            fig.draw_artist(bodies)
            label.set_text(f"t = {tt:6.2f} s")
            fig.draw_artist(label)
            yield np.array(canvas.buffer_rgba(), copy=True)

    return frames()
