"""The physics is plain numerical Python: importable and runnable with rclpy blocked."""

import subprocess
import sys

from conftest import ROOT

CODE = '''
import sys
sys.modules['rclpy'] = None          # any "import rclpy" now raises ImportError
import servovalve_twin.physics as ph
from servovalve_twin.runs import simulate
from servovalve_twin.physics.valves.calibration import calibrate
from servovalve_twin.physics.params import DEFAULTS
r = simulate('C2', {'duration': 0.01})
calibrate(DEFAULTS)
banned = [m for m, mod in sys.modules.items()
          if mod is not None and m.split('.')[0] in ('rclpy', 'rosidl_runtime_py', 'mcap')]
print('loaded', banned)
assert not banned, banned
'''


def test_physics_imports_and_runs_with_rclpy_blocked():
    r = subprocess.run([sys.executable, '-c', CODE], cwd=ROOT, capture_output=True, text=True)
    print(r.stdout, r.stderr[-2000:])
    assert r.returncode == 0
