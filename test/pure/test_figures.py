"""Figures as a paper prints them, the animation and the run's folder (figures.plots,
figures.animation, outputs): units on every axis, nothing over the data, bodies and walls to
scale, headings unwrapped, the error not clamped, PNG at 300 dpi beside a PDF.
"""

import json
import re

import numpy as np
import pytest

from conftest import CONFIG_DIR
from curve_formation.core.config.loading import load_experiment
from curve_formation.core.record import metrics
from curve_formation.core.sim.batch import simulate
from curve_formation.figures import plots


UNIT = re.compile(r'\(.+\)\s*$')


def layout_problems(fig):
    """What a reader would trip over in a figure: an axis without a unit, a legend or text
    over the data region.
    """
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    problems = []
    for ax in fig.axes:
        for which, label in (('x', ax.get_xlabel()), ('y', ax.get_ylabel())):
            if not UNIT.search(label):
                problems.append(f'{ax.get_title()!r}: {which} axis {label!r} has no unit')
        data = ax.get_window_extent(renderer)
        covering = [ax.get_legend()] + [t for t in ax.texts if t.get_text()]
        for artist in covering:
            if artist is not None and artist.get_window_extent(renderer).overlaps(data):
                problems.append(f'{ax.get_title()!r}: {type(artist).__name__} over the data')
        legend = ax.get_legend()
        if legend is not None:
            box, page = legend.get_window_extent(renderer), fig.bbox
            if box.y0 < page.y0 - 1 or box.y1 > page.y1 + 1 or box.x1 > page.x1 + 1:
                problems.append(f'{ax.get_title()!r}: the legend runs off the figure')
    return problems


@pytest.fixture
def checked_figures(monkeypatch):
    """Every figure figures.plots saves, checked before it is written: {file name: figure}."""
    seen = {}
    save = plots._save

    def checking(fig, path):
        problems = layout_problems(fig)
        assert not problems, problems
        seen[path.name if hasattr(path, 'name') else str(path)] = fig
        return save(fig, path)
    monkeypatch.setattr(plots, '_save', checking)
    return seen


@pytest.fixture(scope='module')
def arena_run():
    """The arena demo (bodies, walls, two curves and a switch) simulated for 70 s."""
    experiment = load_experiment(CONFIG_DIR / 'arena_demo.yaml')
    return experiment, simulate(experiment, duration=70.0)


def test_every_figure_has_units_and_keeps_its_legend_off_the_data(arena_run, checked_figures,
                                                                   tmp_path):
    experiment, sim = arena_run
    result = metrics.result_metrics(sim)
    written = plots.run_figures(tmp_path, experiment, sim.t, sim.poses, sim.phase, sim.dhat,
                                result=result)
    assert [p.name for p in written] == ['paths.png', 'error_norm.png', 'orientations.png',
                                         'lyapunov.png']
    assert set(checked_figures) == {p.name for p in written}
    from PIL import Image
    for png in written:
        assert png.with_suffix('.pdf').read_bytes().startswith(b'%PDF')
        with Image.open(png) as image:
            dpi = image.info.get('dpi', (0, 0))[0]
            assert abs(dpi - 300) < 1, (png.name, image.info)


def test_paths_draw_the_walls_and_each_body_to_scale(arena_run, checked_figures, tmp_path):
    from matplotlib.patches import Circle, Rectangle
    experiment, sim = arena_run
    plots.plot_paths(tmp_path / 'paths.png', experiment, sim.poses, sim.phase)
    ax = checked_figures['paths.png'].axes[0]
    walls = [p for p in ax.patches if isinstance(p, Rectangle)]
    assert len(walls) == 1 and (walls[0].get_width(), walls[0].get_height()) == tuple(
        experiment.spec.arena.size)
    bodies = [p for p in ax.patches if isinstance(p, Circle)]
    assert len(bodies) == experiment.n and experiment.radius > 0
    assert all(b.radius == experiment.radius for b in bodies)
    np.testing.assert_allclose(sorted(b.center for b in bodies),
                               sorted(map(tuple, sim.poses[-1, :, :2])))
    labels = ax.get_legend_handles_labels()[1]
    assert {'arena walls', 'start', 'targets', 'end (body to scale)'} <= set(labels), labels
    assert sum(label.startswith('curve ') for label in labels) == len(experiment.phases)


def test_headings_are_unwrapped_and_the_error_is_not_clamped(arena_run, checked_figures,
                                                             tmp_path):
    experiment, sim = arena_run
    plots.plot_orientations(tmp_path / 'orientations.png', experiment, sim.t, sim.poses)
    lines = checked_figures['orientations.png'].axes[0].lines[:experiment.n]
    jumps = [np.abs(np.diff(line.get_ydata())).max() for line in lines]
    assert max(jumps) < np.pi, jumps
    # a formation error reaching 1e-16 is drawn as it is, not at a floor of 1e-12
    norm = np.geomspace(1.0, 1e-16, 50)
    t = np.linspace(0.0, 10.0, 50)
    plots.plot_error_norm(tmp_path / 'error_norm.png', experiment, [('run', t, norm)], 1e-3,
                          settled=[('curve 0', 4.0)])
    ax = checked_figures['error_norm.png'].axes[0]
    assert ax.lines[0].get_ydata().min() == pytest.approx(1e-16)
    assert 'curve 0 settled (4.0 s)' in ax.get_legend_handles_labels()[1]


def test_a_wide_formation_keeps_its_legend_on_the_page(checked_figures, tmp_path):
    experiment = load_experiment(CONFIG_DIR / 'shape_change.yaml')   # 60 m by 18 m
    sim = simulate(experiment, duration=10.0)
    plots.plot_paths(tmp_path / 'paths.png', experiment, sim.poses, sim.phase)
    assert 'paths.png' in checked_figures


def test_robots_keep_their_colour_across_figures():
    colors = plots.robot_colors(9)
    assert len({tuple(c) for c in colors}) == 9
    np.testing.assert_array_equal(colors, plots.robot_colors(9))


def test_the_animation_shows_the_robots_moving(arena_run, tmp_path):
    import imageio_ffmpeg

    from curve_formation.figures.animation import animate, frame_times
    experiment, sim = arena_run
    keep = sim.t <= 20.0
    out = tmp_path / 'film.mp4'
    frames = animate(out, experiment, sim.t[keep], sim.poses[keep], sim.phase[keep],
                     fps=10, max_seconds=4.0)
    times, speed = frame_times(sim.t[keep], 10, 4.0)
    assert frames == len(times) and speed == pytest.approx(5.0)
    reader = imageio_ffmpeg.read_frames(str(out))
    meta = next(reader)
    width, height = meta['size']
    images = [np.frombuffer(f, np.uint8).reshape(height, width, 3) for f in reader]
    assert len(images) == frames
    # the robots move: the first and last frames differ, and every robot's colour is drawn
    assert np.abs(images[0].astype(int) - images[-1].astype(int)).sum() > 0
    colors = (np.asarray(plots.robot_colors(experiment.n))[:, :3] * 255).astype(int)
    last = images[-1].reshape(-1, 3).astype(int)
    for i, color in enumerate(colors):
        near = np.abs(last - color).sum(axis=1) < 60
        assert near.sum() > 20, f'robot {i + 1} not drawn in its colour'


def test_a_gif_is_written_too(arena_run, tmp_path):
    from PIL import Image

    from curve_formation.figures.animation import animate
    experiment, sim = arena_run
    keep = sim.t <= 5.0
    frames = animate(tmp_path / 'film.gif', experiment, sim.t[keep], sim.poses[keep],
                     sim.phase[keep], fps=5, max_seconds=2.0)
    with Image.open(tmp_path / 'film.gif') as gif:
        assert gif.n_frames == frames


def test_sim_leaves_a_folder_a_lab_can_show(tmp_path):
    from curve_formation.cli import main
    assert main(['sim', 'closed_curve', '--out', str(tmp_path), '--animate']) in (0, None)
    for name in ('metrics.json', 'paths.png', 'paths.pdf', 'error_norm.png', 'trajectory.npz',
                 'experiment.yaml', 'animation.mp4', 'report.html'):
        assert (tmp_path / name).exists(), name
    page = (tmp_path / 'report.html').read_text()
    result = json.loads((tmp_path / 'metrics.json').read_text())
    assert 'Curve 0 settled' in page and result['phases'][0]['settled']
    assert 'data:video/mp4;base64,' in page and page.count('data:image/png;base64,') >= 3
    assert 'http://' not in page and 'https://' not in page   # nothing from the network


def test_animate_takes_a_run_folder_and_refuses_what_is_not_one(tmp_path, capsys):
    from PIL import Image

    from curve_formation.cli import main
    run = tmp_path / 'run'
    assert main(['sim', 'open_curve', '--out', str(run)]) in (0, None)
    assert main(['animate', str(run), '--out', str(tmp_path / 'film.gif'), '--fps', '5',
                 '--max-seconds', '3']) in (0, None)
    with Image.open(tmp_path / 'film.gif') as gif:
        assert gif.n_frames == 16   # 3 s at 5 fps, both ends
    assert 'frames of open_curve' in capsys.readouterr().out
    assert main(['animate', str(tmp_path), '--out', str(tmp_path / 'x.mp4')]) == 2
    assert 'neither a run folder (trajectory.npz) nor a ROS 2 bag' in capsys.readouterr().err


def test_the_film_can_show_the_overhead_cameras_view_and_its_markers_are_found(tmp_path):
    """`animate --camera`: beside the plan, the overhead camera's frame as fake_camera renders
    it, in which the tracker's detector finds every robot's marker.
    """
    import imageio_ffmpeg

    from curve_formation.cli import main
    from curve_formation.vision.markers import MarkerLayout
    from curve_formation.vision.render import camera_view
    from curve_formation.vision.tracker import MarkerTracker
    experiment = load_experiment(CONFIG_DIR / 'arena_demo.yaml')
    sim = simulate(experiment, duration=5.0)
    frame = camera_view(experiment, (1280, 720))(sim.poses[-1])
    layout = MarkerLayout.from_spec(experiment.spec.camera)
    found = MarkerTracker(layout, continuous=False, refinement='contour').detect(frame)
    assert set(layout.robot_ids) <= set(found), sorted(found)
    run = tmp_path / 'run'
    assert main(['sim', 'arena_demo', '--out', str(run)]) in (0, None)
    sizes = {}
    for camera in (False, True):
        film = tmp_path / f'film{camera}.mp4'
        assert main(['animate', str(run), '--out', str(film), '--fps', '4', '--max-seconds',
                     '2'] + (['--camera'] if camera else [])) in (0, None)
        reader = imageio_ffmpeg.read_frames(str(film))
        sizes[camera] = next(reader)['size']
        width, height = sizes[camera]
        last = np.frombuffer(list(reader)[-1], np.uint8).reshape(height, width, 3)
    assert sizes[True][0] > sizes[False][0] + 300   # a second panel
    assert last[:, -width // 3:].std() > 20   # the camera's frame, not a blank panel
