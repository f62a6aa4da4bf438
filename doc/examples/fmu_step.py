"""The actuator's FMU in FMPy: a 20 mm position step at 20 MPa supply, no load, 0.3 s; prints
where the jack is at 0.05, 0.1 and 0.3 s. Any FMI 2.0 co-simulation importer does the same.

    servovalve-twin fmu --valve-model SQ eha_sq.fmu
    .venv/bin/python doc/examples/fmu_step.py eha_sq.fmu
"""

import sys

import numpy as np
from fmpy import simulate_fmu

# the inputs, held from each row's time on (as the twin holds them): Com [m], FR [N], PSR [Pa];
# FMPy wants two rows at least
inputs = np.array([(0.0, 0.02, 0.0, 2.0e7), (0.3, 0.02, 0.0, 2.0e7)],
                  dtype=[('time', float), ('com', float), ('fr', float), ('psr', float)])
r = simulate_fmu(sys.argv[1], stop_time=0.3, output_interval=1e-3, input=inputs,
                 output=['xj', 'dxj', 'p12', 'xs'])
for t in (0.05, 0.1, 0.3):
    i = int(np.argmin(np.abs(r['time'] - t)))
    print(f't = {r["time"][i]:.3f} s: XJ {r["xj"][i] * 1e3:6.2f} mm, DXJ {r["dxj"][i] * 1e3:7.2f} '
          f'mm/s, P12 {r["p12"][i] / 1e6:5.2f} MPa')
