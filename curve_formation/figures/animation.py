"""An animation of a run: robots as bodies with their heading, their targets, the curve as it
was followed (switching, moving), short trails, the run's time.

MP4 (H.264 through the ffmpeg binary of the imageio-ffmpeg wheel) or GIF (Pillow), by the
output's suffix. A long run is played faster than real time so that the film lasts at most
`max_seconds`; the speed-up is written on every frame. Inputs as figures.plots: t (R,) s,
poses (R, n, 3) (m, m, rad) in the arena frame, phase (R,) indices into experiment.phases.
"""

from pathlib import Path

import matplotlib


matplotlib.use('Agg')
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from curve_formation.core.formation import dynamics
from curve_formation.core.record import metrics  # noqa: E402
from curve_formation.figures.plots import draw_arena, robot_colors, STYLE  # noqa: E402


FPS = 15
TRAIL = 5.0            # s of path drawn behind each robot
CURVE_SAMPLES = 300


def frame_times(t, fps=FPS, max_seconds=30.0):
    """The run times (s) shown, one per frame, and the speed-up (run s per film s)."""
    duration = float(t[-1] - t[0])
    speed = max(1.0, duration / max_seconds)
    return t[0] + np.arange(0.0, duration + 1e-9, speed / fps), speed


def animate(path, experiment, t, poses, phase, fps=FPS, max_seconds=30.0, dpi=100,
            title=None, camera_view=None):
    """Write the film to `path` (.mp4 or .gif); returns the number of frames.
    camera_view: optional poses (n, 3) -> image (grey or RGB uint8), drawn beside the plan
    at each frame (e.g. vision.render.camera_view: the overhead camera's frame).
    """
    path = Path(path)
    if path.suffix not in ('.mp4', '.gif'):
        raise ValueError(f'{path}: the animation is written as .mp4 or .gif')
    t, poses, phase = np.asarray(t, float), np.asarray(poses, float), np.asarray(phase)
    times, speed = frame_times(t, fps, max_seconds)
    rows = np.clip(np.searchsorted(t, times, side='right') - 1, 0, len(t) - 1)
    targets = metrics.sample_targets(experiment, phase[rows], t[rows])
    xb = dynamics.offset_points(poses, experiment.gains.offset)
    n, radius = experiment.n, experiment.radius
    colors = robot_colors(n)
    with plt.rc_context(STYLE):
        fig = plt.figure(figsize=(6.4, 5.4), dpi=dpi, layout='constrained')
        ax = fig.add_subplot(1, 2 if camera_view else 1, 1)
        aspect = _frame_axes(ax, experiment, poses, xb)
        # axes about 4.6 in wide, the legend beside them; whole pixels, even (H.264)
        width, height = 6.8, float(np.clip(4.6 * aspect + 0.9, 2.6, 7.0))
        view = None
        if camera_view is not None:
            frame = np.asarray(camera_view(poses[rows[0]]))
            width, height = width + 4.6, max(height, 4.6 * frame.shape[0] / frame.shape[1] + 0.9)
            cam_ax = fig.add_subplot(1, 2, 2)
            view = cam_ax.imshow(frame, cmap='gray', vmin=0, vmax=255)
            cam_ax.set_axis_off()
            cam_ax.set_title('the overhead camera (rendered)')
        fig.set_size_inches(*(2 * np.round(np.array([width, height]) * dpi / 2) / dpi))
        curve_line, = ax.plot([], [], color='0.15', lw=1.1, ls='--', label='curve')
        target_dots = ax.scatter(targets[0, :, 0], targets[0, :, 1], marker='*', s=60,
                                 color=colors, edgecolors='0.15', linewidths=0.5, zorder=3,
                                 label='targets')
        trails = [ax.plot([], [], color=colors[i], lw=0.8, alpha=0.8)[0] for i in range(n)]
        size = radius if radius > 0 else 0.015 * _span(ax)
        reach = 1.4 * max(size, 1e-9)   # the heading's line (m)
        bodies = [Circle((0, 0), size, fill=radius > 0, color=colors[i], lw=1.2, zorder=4)
                  for i in range(n)]
        for body in bodies:
            ax.add_patch(body)
        headings = [ax.plot([], [], color='0.1', lw=1.2, zorder=5)[0] for _ in range(n)]
        clock = ax.text(0.01, 0.99, '', transform=ax.transAxes, va='top', ha='left',
                        fontsize=9, bbox={'fc': 'white', 'ec': '0.7', 'alpha': 0.85})
        ax.plot([], [], 'o', color='0.4', mfc='none' if radius > 0 else '0.4',
                label='robots (body to scale)' if radius > 0 else 'robots')
        ax.legend(loc='upper left', bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
        ax.set_title(title or f'{experiment.name}')
        moving = [curve_line, target_dots, *trails, *bodies, *headings, clock]
        if view is not None:
            moving.append(view)
        for artist in moving:          # drawn on a still background, frame by frame
            artist.set_animated(True)
        canvas = fig.canvas
        assert isinstance(canvas, FigureCanvasAgg)   # the Agg backend, chosen above
        canvas.draw()
        fig.set_layout_engine('none')   # laid out once
        background = canvas.copy_from_bbox(fig.bbox)
        drawn_curve = [None]   # the phase whose curve is drawn (a moving one: every frame)

        def draw(k):
            r, now = rows[k], times[k]
            p = experiment.phases[int(phase[r])]
            if drawn_curve[0] != p.index or p.motion is not None:
                line = p.curve_at(float(now)).outline(CURVE_SAMPLES)
                curve_line.set_data(line[:, 0], line[:, 1])
                drawn_curve[0] = p.index
            target_dots.set_offsets(targets[k])
            first = max(0, np.searchsorted(t, now - TRAIL))
            for i in range(n):
                x, y, theta = poses[r, i]
                trails[i].set_data(xb[first:r + 1, i, 0], xb[first:r + 1, i, 1])
                bodies[i].center = (x, y)
                headings[i].set_data([x, x + reach * np.cos(theta)],
                                     [y, y + reach * np.sin(theta)])
            clock.set_text(f't = {now:6.1f} s   curve {p.index}   x{speed:.3g} speed')
            if view is not None:
                view.set_data(camera_view(poses[r]))
            canvas.restore_region(background)
            for artist in moving:
                fig.draw_artist(artist)
            return np.asarray(canvas.buffer_rgba())[..., :3].copy()

        path.parent.mkdir(parents=True, exist_ok=True)
        _write(path, (draw(k) for k in range(len(times))), canvas.get_width_height(), fps)
        plt.close(fig)
    return len(times)


def _write(path, frames, size, fps):
    """Frames (H, W, 3 uint8) to an MP4 (H.264, ffmpeg from imageio-ffmpeg) or a GIF."""
    if path.suffix == '.gif':
        from PIL import Image
        images = [Image.fromarray(frame) for frame in frames]
        images[0].save(path, save_all=True, append_images=images[1:],
                       duration=round(1000 / fps), loop=0)
        return
    import imageio_ffmpeg  # type: ignore[import-untyped]
    writer = imageio_ffmpeg.write_frames(str(path), size, fps=fps, codec='libx264',
                                         pix_fmt_out='yuv420p', macro_block_size=2,
                                         output_params=['-preset', 'veryfast'])
    writer.send(None)
    try:
        for frame in frames:
            writer.send(frame.tobytes())
    finally:
        writer.close()


def _span(ax):
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    return max(x1 - x0, y1 - y0)


def _frame_axes(ax, experiment, poses, xb):
    """Limits that hold the arena (or every pose, offset point and curve), equal scale;
    returns their height over their width.
    """
    arena = experiment.spec.arena
    draw_arena(ax, arena)
    if arena is not None:
        points = np.array([[0.0, 0.0], arena.size])
    else:
        curves = [p.curve.sample(CURVE_SAMPLES)[1] for p in experiment.phases]
        points = np.vstack([poses[..., :2].reshape(-1, 2), xb.reshape(-1, 2), *curves])
        points = points[np.isfinite(points).all(axis=1)]
    low, high = points.min(axis=0), points.max(axis=0)
    pad = 0.05 * max(high - low) + experiment.radius
    ax.set_xlim(low[0] - pad, high[0] + pad)
    ax.set_ylim(low[1] - pad, high[1] + pad)
    ax.set_aspect('equal')
    ax.set_xlabel('x (m)')
    ax.set_ylabel('y (m)')
    return (high[1] - low[1] + 2 * pad) / (high[0] - low[0] + 2 * pad)
