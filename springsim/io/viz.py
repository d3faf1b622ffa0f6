"""Pictures of simulations: a DoF plotted over time, rendered frames and animated GIFs.

matplotlib is an optional extra (``pip install 'springsim[plot]'``) imported only
when a function here is called. Figures are standalone ``matplotlib.figure.Figure``
objects, so no backend, display or ``MPLBACKEND`` setting is needed, and pyplot's state is
left alone. Pictures are written atomically (:func:`springsim.io._atomic.write_atomic`): a failed or
interrupted render leaves the previous file as it was; the directory must exist. Springs are drawn as line segments (one ``Line3DCollection``), a cloth grid
(``model.cloth_grids``) as a shaded surface (its own springs are the surface; every other
spring stays a line), free particles as dots and fixed ones as black squares.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import SpringsimError
from ..model.topology import springs_outside_grids

__all__ = ["plot_dof", "render_frame", "render_gif", "require_matplotlib", "run_title", "springs_outside_grids",
           "DOF_NAMES"]

#: Names accepted for a coordinate, besides 0, 1, 2.
DOF_NAMES = {"x": 0, "y": 1, "z": 2}


def require_matplotlib():
    """Return :class:`matplotlib.figure.Figure`, or raise :class:`SpringsimError` without matplotlib.

    springsim draws on standalone figures (no pyplot, no global backend): nothing here depends
    on ``MPLBACKEND`` or a display, and the caller's pyplot state is left alone.

    Returns
    -------
    type
        The class :class:`matplotlib.figure.Figure`.

    Raises
    ------
    SpringsimError
        matplotlib is not installed (the message gives the install command).
    """
    try:
        import matplotlib  # noqa: F401  (first: a missing matplotlib is found even if a submodule is cached)
        from matplotlib.figure import Figure
    except ImportError:
        raise SpringsimError("matplotlib is needed for plots and renders: pip install 'springsim[plot]'") from None
    return Figure


def _dof_index(dof) -> int:
    if isinstance(dof, str):
        if dof.lower() not in DOF_NAMES:
            raise SpringsimError(f"plot.dof: must be x, y, z or 0, 1, 2, got {dof!r}")
        return DOF_NAMES[dof.lower()]
    if int(dof) != dof or not 0 <= dof <= 2:
        raise SpringsimError(f"plot.dof: must be x, y, z or 0, 1, 2, got {dof!r}")
    return int(dof)


def plot_dof(traj, particle_id: int, dof, y_range=None, out_png=None, *, title: str | None = None,
             dpi: int = 100):
    """Plot one coordinate of one particle over time (the scene's ``plot:`` block).

    Parameters
    ----------
    traj : Trajectory
        Frames ``t`` (F,) [s] and ``q`` (F, N, 3) [m].
    particle_id : int
        Particle index, ``0 <= particle_id < N``.
    dof : int or {"x", "y", "z"}
        Coordinate.
    y_range : (float, float), optional
        Vertical axis limits [m].
    out_png : path, optional
        Where to write the picture (atomically; its extension names the format, ``.png``, ``.svg``, ...); if
        None the figure is returned open.
    title : str, optional
        Title of the plot.
    dpi : int
        Resolution of the written picture [dots per inch].

    Returns
    -------
    Path or matplotlib.figure.Figure
        ``out_png`` as a path, or the figure.

    Raises
    ------
    SpringsimError
        An invalid ``dof`` or ``particle_id``, an unknown picture extension, no matplotlib.
    """
    Figure = require_matplotlib()
    k = _dof_index(dof)
    n = traj.q.shape[1]
    if int(particle_id) != particle_id or not 0 <= particle_id < n:
        raise SpringsimError(f"plot.particle: must be in [0, {n}), got {particle_id!r}")
    fig = Figure(figsize=(6.0, 3.4))
    ax = fig.subplots()
    ax.plot(traj.t, traj.q[:, int(particle_id), k], lw=1.2)
    ax.set_xlabel("t [s]")
    ax.set_ylabel(f"particle {int(particle_id)} {'xyz'[k]} [m]")
    if y_range is not None:
        ax.set_ylim(float(y_range[0]), float(y_range[1]))
    ax.grid(True, alpha=0.3)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    if out_png is None:
        return fig
    return _save_figure(fig, out_png, dpi)


def _save_figure(fig, out, dpi) -> Path:
    """Save ``fig`` to ``out`` atomically (:func:`springsim.io._atomic.write_atomic`), in the format its extension
    names."""
    from ._atomic import write_atomic

    ext = Path(out).suffix.lower()[1:]
    known = fig.canvas.get_supported_filetypes()
    if ext not in known:
        raise SpringsimError(f"{out}: unknown picture extension {'.' + ext if ext else '(none)'}; give a name "
                             f"ending in {', '.join('.' + k for k in sorted(known))}")
    # the format given explicitly: matplotlib writes exactly the temporary file, never "<name>.png"
    write_atomic(out, lambda tmp: fig.savefig(tmp, dpi=dpi, format=ext))
    return Path(out)


def run_title(traj, scene: str | None = None) -> str:
    """``"<scene>: <integrator>, h = <dt> s"`` from a trajectory's :attr:`~springsim.run.driver.Trajectory.meta`
    (adaptive runs: ``"adaptive, rtol = ..."``); the parts the metadata lacks are left out.

    Parameters
    ----------
    traj : Trajectory
        A trajectory from :func:`springsim.simulate` or :func:`springsim.simulate_adaptive` (or loaded).
    scene : str, optional
        Scene name; default ``traj.meta["scene"]``.

    Returns
    -------
    str
        The title.
    """
    m = traj.meta
    scene = scene if scene is not None else m.get("scene")
    parts = [m["integrator"]] if m.get("integrator") else []
    if m.get("dt") is not None:
        parts.append(f"h = {m['dt']:.4g} s")
    elif m.get("time_rtol") is not None:
        parts.append(f"adaptive, rtol = {m['time_rtol']:g}")
    body = ", ".join(parts)
    return f"{scene}: {body}" if scene and body else (scene or body)


#: Largest coordinate [m] a picture draws: the 3D projection multiplies coordinates, which must not overflow.
MAX_DRAWN_COORDINATE = 1e100


def _bounds(q: np.ndarray):
    """Cube bounds (lo, hi) (3,) around all finite positions in ``q`` (..., 3), equal extents.

    Raises
    ------
    SpringsimError
        When a finite coordinate exceeds :data:`MAX_DRAWN_COORDINATE` in magnitude.
    """
    pts = q.reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if pts.size == 0:
        return -np.ones(3), np.ones(3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    big = float(max(np.max(np.abs(lo)), np.max(np.abs(hi))))
    if big > MAX_DRAWN_COORDINATE:
        raise SpringsimError(f"render: positions reach {big:.3g} m; pictures draw coordinates up to "
                             f"{MAX_DRAWN_COORDINATE:g} m in magnitude")
    c, r = 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo))
    r = r * 1.05 if r > 0 else 1.0
    return c - r, c + r


def _draw(ax, model, q: np.ndarray, *, show_springs: bool, show_particles: bool, surface: bool):
    """Draw one configuration ``q`` (N, 3) into a 3D axes; returns the artists."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    artists = []
    n = q.shape[0]
    springs = np.arange(model.spring_count)
    if surface and model.cloth_grids:
        for start, nx, ny in model.cloth_grids:
            g = q[start:start + nx * ny].reshape(ny, nx, 3)
            artists.append(ax.plot_surface(g[..., 0], g[..., 1], g[..., 2], color="tab:orange", shade=True,
                                           linewidth=0.2, edgecolor="0.4", alpha=0.95, antialiased=True))
        springs = springs_outside_grids(model)  # the grids' own springs are the surface
    if show_springs and springs.size:
        lc = Line3DCollection(q[model.spring_indices[springs]], colors="tab:blue", linewidths=0.8)
        ax.add_collection3d(lc)
        artists.append(lc)
    if show_particles:
        fixed = np.asarray(model.particle_fixed, dtype=bool)
        if n <= 2000:
            free = ~fixed
            artists.append(ax.scatter(q[free, 0], q[free, 1], q[free, 2], s=8, c="tab:red", depthshade=False))
        if fixed.any():
            artists.append(ax.scatter(q[fixed, 0], q[fixed, 1], q[fixed, 2], s=14, c="k", marker="s",
                                      depthshade=False))
    return artists


def _axes(Figure, lo, hi, size):
    fig = Figure(figsize=size)
    ax = fig.add_subplot(projection="3d")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    return fig, ax


def render_frame(model, q: np.ndarray, out_png, *, title: str | None = None, bounds=None,
                 show_springs: bool = True, show_particles: bool = True, surface: bool = True,
                 elev: float = 20.0, azim: float = -60.0, size=(6.0, 6.0), dpi: int = 100):
    """Render one configuration of ``model`` to a PNG (600 px square by default).

    Parameters
    ----------
    model : Model
        The model (its springs, cloth grids and radii are drawn).
    q : ndarray (N, 3)
        Particle positions [m].
    out_png : path
        Where to write the picture (atomically; its extension names the format).
    title : str, optional
        Title of the picture.
    bounds : (lo, hi), optional
        Axis limits, each (3,) [m]; default a cube around ``q``.
    show_springs, show_particles, surface : bool
        What to draw (a cloth is drawn as a surface instead of its springs when ``surface``).
    elev, azim : float
        View angles [deg].
    size : (float, float)
        Figure size [in]; with ``dpi`` it sets the image size.
    dpi : int
        Resolution [dots per inch]; default 100 (600 px for the default size).

    Returns
    -------
    Path
        ``out_png``.

    Raises
    ------
    SpringsimError
        ``q`` of the wrong shape, an unknown picture extension, no matplotlib.
    """
    Figure = require_matplotlib()
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (model.particle_count, 3):
        raise SpringsimError(f"render: positions must have shape ({model.particle_count}, 3), got {q.shape}")
    lo, hi = _bounds(q) if bounds is None else (np.asarray(bounds[0]), np.asarray(bounds[1]))
    fig, ax = _axes(Figure, lo, hi, size)
    ax.view_init(elev=elev, azim=azim)
    _draw(ax, model, q, show_springs=show_springs, show_particles=show_particles, surface=surface)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return _save_figure(fig, out_png, dpi)


def render_gif(model, traj, out_gif, *, every: int = 1, fps: int = 20, show_springs: bool = True,
               show_particles: bool = True, surface: bool = True, elev: float = 20.0, azim: float = -60.0,
               size=(6.0, 6.0), dpi: int = 80, title: str | None = None):
    """Animated GIF of every ``every``-th frame of ``traj`` (matplotlib's PillowWriter; 480 px square by default).

    Parameters
    ----------
    model : Model
        The model (its springs, cloth grids and radii are drawn).
    traj : Trajectory
        Frames ``t`` (F,) [s], ``q`` (F, N, 3) [m].
    out_gif : path
        Where to write the animation (atomically); the name must end in ``.gif``.
    every : int
        Frame stride (>= 1); the last frame is always included.
    fps : int
        Frames per second of the animation.
    show_springs, show_particles, surface : bool
        What to draw (a cloth is drawn as a surface instead of its springs when ``surface``).
    elev, azim : float
        View angles [deg].
    size : (float, float)
        Figure size [in]; with ``dpi`` it sets the image size.
    dpi : int
        Resolution [dots per inch]; default 80 (480 px for the default size).
    title : str, optional
        Title of every frame, followed by the frame's time (default :func:`run_title` of ``traj``).

    Returns
    -------
    Path
        ``out_gif``.

    Raises
    ------
    SpringsimError
        An invalid ``every``, a name not ending in ``.gif``, a trajectory without frames, no matplotlib.
    """
    Figure = require_matplotlib()
    from matplotlib.animation import PillowWriter

    title = run_title(traj) if title is None else title

    if int(every) != every or every < 1:
        raise SpringsimError(f"render.every: must be an integer >= 1, got {every!r}")
    if Path(out_gif).suffix.lower() != ".gif":
        raise SpringsimError(f"{out_gif}: an animated GIF needs a name ending in .gif")
    if traj.q.shape[0] == 0:
        raise SpringsimError("render: the trajectory has no frames")
    frames = list(range(0, traj.q.shape[0], int(every)))
    if frames[-1] != traj.q.shape[0] - 1:
        frames.append(traj.q.shape[0] - 1)
    lo, hi = _bounds(traj.q[frames])
    fig, ax = _axes(Figure, lo, hi, size)

    def write(tmp):  # PillowWriter writes the file when the block ends, also when it ends by an exception
        writer = PillowWriter(fps=fps)
        with writer.saving(fig, tmp, dpi):
            for k in frames:
                for coll in list(ax.collections):
                    coll.remove()
                ax.view_init(elev=elev, azim=azim)
                _draw(ax, model, traj.q[k], show_springs=show_springs, show_particles=show_particles,
                      surface=surface)
                ax.set_title(f"{title}\nt = {traj.t[k]:.3f} s" if title else f"t = {traj.t[k]:.3f} s")
                writer.grab_frame()

    from ._atomic import write_atomic

    write_atomic(out_gif, write)  # an interrupted or failed render leaves the previous file as it was
    return Path(out_gif)
