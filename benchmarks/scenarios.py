"""Experiments built in code for the benchmarks: n agents on a wavy closed curve."""

from curve_formation.core.config.loading import build_experiment


def scaled_experiment(n, seed=0, duration=10.0, disturbance=(1.0, 1.0), law='paper',
                      heading='paper', max_wheel_speed=5.0):
    """n agents, Fourier K = n // 2 (so n <= H), a chain from the leader plus skip edges.

    Case-1 gains (k1 = k2 = 1, l = 0.01), 10 Hz, starts spread over +-12, wheel base 0.1.
    """
    edges = [{'from': i, 'to': i + 1} for i in range(1, n)]
    edges += [{'from': i, 'to': i + 2} for i in range(1, n - 1, 3)]
    return build_experiment({
        'name': f'scale_{n}',
        'agents': {'count': n, 'initial': {'random': {'seed': seed, 'center': [0, 0],
                                                      'half_width': [12, 12]}}},
        'graph': {'edges': edges},
        'controller': {'law': law, 'heading': heading, 'k1': 1.0, 'k2': 1.0, 'offset': 0.01,
                       'rate_hz': 10.0},
        'disturbance': {'value': list(disturbance)},
        'limits': {'wheel_base': 0.1, 'max_wheel_speed': max_wheel_speed},
        'curves': [{'basis': 'fourier', 'harmonics': max(1, n // 2),
                    'samples': max(400, 3 * n + 3),
                    'x': '(8 + sin(6*pi*s)) * cos(2*pi*s)',
                    'y': '(8 + cos(4*pi*s)) * sin(2*pi*s)'}],
        'simulation': {'duration': duration, 'dt': 0.001, 'record_dt': 0.1},
    }, f'<scale {n}>')
