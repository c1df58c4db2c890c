"""A node console script started without a required parameter says so in one line naming
the fix.
"""

import subprocess
import sys


def test_a_missing_required_parameter_is_one_line_naming_the_fix(ros_domain):
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.nodes.formation_controller'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().count('\n') == 0, proc.stderr
    assert "parameter 'index' is required" in proc.stderr
    assert '`-p index:=VALUE`' in proc.stderr and 'curve-formation params' in proc.stderr
