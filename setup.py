"""ament_python package: `colcon build` installs the node executables under
lib/servovalve_twin/ (setup.cfg) so that `ros2 run servovalve_twin <node>` finds them; a plain
`pip install` puts the same console scripts in bin/."""

import os
import subprocess
import sys
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

package_name = 'servovalve_twin'


class build_py_and_loops(build_py):
    """The package, and the step loops compiled ahead of time beside it
    (``python -m servovalve_twin.aot``): a plain ``pip install .`` (pyproject.toml brings numba
    into the build) or a ``colcon build`` then runs a model without compiling it. Not for an
    editable install (``scripts/setup`` builds the module in the source tree), nor with
    SERVOVALVE_TWIN_NO_AOT set; where it cannot be built the loops compile on first use."""

    def run(self):
        super().run()
        if getattr(self, 'editable_mode', False) or os.environ.get('SERVOVALVE_TWIN_NO_AOT'):
            return
        here = Path(__file__).resolve().parent
        dest = Path(self.build_lib).resolve() / package_name
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            p for p in (str(here), os.environ.get('PYTHONPATH')) if p))
        print('servovalve_twin: compiling the step loops ahead of time (gcc; 2-5 min) ...',
              file=sys.stderr, flush=True)
        r = subprocess.run([sys.executable, '-m', 'servovalve_twin.aot', '--dest', str(dest)],
                           cwd=here, env=env)
        if r.returncode:
            print('servovalve_twin: the loops could not be compiled ahead of time; each model '
                  'compiles on first use instead (2-5 s)', file=sys.stderr, flush=True)

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    # the HD reference bag of the paper scenario, read-only to every command (servovalve-twin
    # compare @paper_HD RUN); the diagnosis' model-form calibration (bench/calibrate_diagnosis.py)
    # and the monitor's thresholds (bench/calibrate_monitor.py)
    package_data={'servovalve_twin': ['data/paper_HD/*', 'data/*.json']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.json')),
        ('share/' + package_name + '/config/scenarios', glob('config/scenarios/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools', 'numpy', 'numba', 'pyyaml', 'mcap', 'zstandard', 'lz4',
                      'matplotlib', 'tqdm', 'pyarrow', 'scipy>=1.16'],
    # 'test': what the suite needs beyond the package (colcon test runs pytest when it is here)
    extras_require={'foxglove': ['websockets'], 'dask': ['dask[distributed]'],
                    # servovalve_twin.progpy: the EHA as a NASA progpy PrognosticsModel
                    'progpy': ['progpy'],
                    # servovalve-twin fmu: an FMI 2.0 co-simulation FMU of the actuator
                    'fmu': ['pythonfmu'],
                    'test': ['pytest', 'rosbags', 'mcap-ros2-support', 'websockets', 'progpy',
                             'pythonfmu', 'fmpy', 'ruff']},
    python_requires='>=3.10',
    cmdclass={'build_py': build_py_and_loops},
    zip_safe=False,
    maintainer='servovalve_twin maintainers',
    maintainer_email='maintainers@servovalve-twin.invalid',
    description='Digital twin of an aerospace electro-hydraulic actuator (ROS 2 Jazzy).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'servovalve-twin = servovalve_twin.entry:cli',
            'command_generator = servovalve_twin.entry:command_generator',
            'load_supply = servovalve_twin.entry:load_supply',
            'ecu = servovalve_twin.entry:ecu',
            'plant = servovalve_twin.entry:plant',
            'clock = servovalve_twin.entry:clock',
            'monitor = servovalve_twin.entry:monitor',
            'twin = servovalve_twin.entry:twin',
            'replay = servovalve_twin.entry:replay',
            'player = servovalve_twin.entry:player',
            'algorithm = servovalve_twin.entry:algorithm',
        ],
        # the fixtures ros_context, replay and twin_bag for every test suite (testing/plugin.py)
        'pytest11': ['servovalve_twin = servovalve_twin.testing.plugin'],
    },
)
