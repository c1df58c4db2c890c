"""Bad input: every malformed experiment file of the test corpus refused by `curve-formation
check` in its own process, with its time, peak memory and error line length; and `check` on a
valid 1000-agent experiment.

Run: scripts/bench bad_input
Goal (issue): each refused within 5 s and 1 GB with one line under 500 characters; no
traceback; check of 1000 agents within 30 s. Also a 5000-agent file with a 5-function
basis, refused by Assumption 2 before Theorem 1's O(n^3) certificate is computed (it took
over a minute when the certificate came first).
"""

from pathlib import Path
import resource
import subprocess
import sys
import tempfile
import time

import yaml


TEST_DIR = Path(__file__).resolve().parent.parent / 'test'
MEMORY_LIMIT = 1 << 30   # address space of each check process (bytes)


def check(path):
    """(seconds, peak MB, exit status, stderr) of `curve-formation check PATH` in a process
    limited to MEMORY_LIMIT of address space.
    """
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    started = time.perf_counter()
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'check', str(path)],
                          capture_output=True, text=True, preexec_fn=limit, timeout=120)
    seconds = time.perf_counter() - started
    peak = max(before, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss) / 1024
    return seconds, peak, proc.returncode, proc.stderr


def thousand_agents(folder):
    n = 1000
    path = Path(folder) / 'agents_1000.yaml'
    path.write_text(yaml.safe_dump({
        'name': 'agents_1000',
        'agents': {'count': n, 'initial': {'random': {'seed': 1, 'center': [0, 0],
                                                      'half_width': [50, 50]}}},
        'graph': {'edges': [{'from': i, 'to': i + 1} for i in range(1, n)], 'pinning': 1.0},
        'controller': {'law': 'observer', 'heading': 'sampled', 'k1': 1.0, 'k2': 1.0,
                       'offset': 0.01, 'rate_hz': 10.0},
        'curves': [{'basis': 'fourier', 'harmonics': 500, 'samples': 2500,
                    'x': '40*cos(2*pi*s)', 'y': '40*sin(2*pi*s)'}],
        'simulation': {'duration': 10.0}}))
    return path


def too_few_functions(folder, n=5000):
    path = Path(folder) / 'agents_5000_basis_5.yaml'
    path.write_text(yaml.safe_dump({
        'name': 'agents_5000_basis_5',
        'agents': {'count': n, 'initial': {'random': {'seed': 1, 'center': [0, 0],
                                                      'half_width': [50, 50]}}},
        'graph': {'edges': [{'from': i, 'to': i + 1} for i in range(1, n)]},
        'controller': {'k1': 1.0, 'k2': 1.0, 'offset': 0.01, 'rate_hz': 10.0},
        'curves': [{'basis': 'fourier', 'harmonics': 2,
                    'x': '40*cos(2*pi*s)', 'y': '40*sin(2*pi*s)'}],
        'simulation': {'duration': 10.0}}))
    return path


def main():
    sys.path.insert(0, str(TEST_DIR))
    from test_bad_input import BAD
    worst = {'seconds': 0.0, 'line': 0}
    print(f'{"file":30s} {"s":>6s} {"peak MB":>8s} {"status":>6s} {"line":>5s}  error line')
    with tempfile.TemporaryDirectory() as folder:
        for name, (content, _) in BAD.items():
            path = Path(folder) / 'bad.yaml'
            path.write_bytes(content if isinstance(content, bytes) else content.encode())
            seconds, peak, status, err = check(path)
            lines = err.strip().splitlines()
            length = max((len(line) for line in lines), default=0)
            traceback = 'Traceback' in err
            worst['seconds'] = max(worst['seconds'], seconds)
            worst['line'] = max(worst['line'], length)
            print(f'{name:30s} {seconds:6.2f} {peak:8.0f} {status:6d} {length:5d}  '
                  f'{(lines[0] if lines else "")[:70]}'
                  + ('  TRACEBACK' if traceback or len(lines) != 1 else ''))
        seconds, peak, status, err = check(thousand_agents(folder))
        few = check(too_few_functions(folder))
    print(f'\nworst: {worst["seconds"]:.2f} s, line {worst["line"]} characters (peak memory of '
          'any one check: see the column; limit 1 GB)')
    print(f'check of 1000 agents: {seconds:.1f} s, exit {status}, peak {peak:.0f} MB')
    print(f'5000 agents, a 5-function basis: refused in {few[0]:.1f} s, exit {few[2]}, peak '
          f'{few[1]:.0f} MB: {few[3].strip().splitlines()[-1][:120] if few[3] else ""}')


if __name__ == '__main__':
    main()
