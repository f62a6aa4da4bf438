"""The FMU's model: an FMI 2.0 co-simulation slave (pythonfmu) of the EHA.

``servovalve-twin fmu`` packs this file into the FMU with ``eha_fmu.json`` (the valve model and
control period it was built for), ``requirements.txt`` and a copy of the package's physics as
resources (the package ``_servovalve_twin_fmu``: this file is the FMU's script, not a module
of servovalve_twin to import). It runs in the importing tool's Python (pythonfmu FMUs need a
Python to execute: the FMU says so, ``needsExecutionTool``), which must have numpy and numba
(``requirements.txt``); a missing one is one message in the FMU's log naming what to install.
The first instance in a process compiles the physics (numba; seconds), as the FMU is unpacked
afresh by each run.

Variables: inputs ``com`` [m], ``fr`` [N], ``psr`` [Pa] -- *discrete*, held over a
communication step as the twin holds them over a control period (an importer must not
interpolate them); outputs ``xj``, ``dxj``, ``p12``, ``xs``; parameters every settable EHA
parameter under its name (derived ones derive from them), ``control_period`` and, in an FMU
built with sensors (``fmu --sensors``), ``sensor_seed``: the outputs are then what the sensors
read and the ECU closes its loop on the measured XJ, as in ``simulate``. A step is a
whole number of control periods of the ROS plant's compiled tick
(:class:`servovalve_twin.physics.simulate.EhaPlant`), so the outputs are ``simulate``'s.
"""

import json
from pathlib import Path
from xml.etree.ElementTree import SubElement

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real

try:
    import numpy  # noqa: F401
    import numba  # noqa: F401
except ImportError as exc:   # the importer's Python lacks what the FMU declares it needs
    raise ImportError(
        f'the EHA FMU needs the Python packages numpy and numba in the Python that runs it '
        f'({exc}); install them (pip install numpy numba), or run `pythonfmu deploy -f '
        f'<this>.fmu`, which installs resources/requirements.txt') from None

# the package's physics as the FMU carries it (servovalve_twin.fmu.CARRIED_AS): a copy under
# its own name, so that it never shadows an installed servovalve_twin in the importing process
from _servovalve_twin_fmu.errors import TwinError
from _servovalve_twin_fmu.physics.params import DEFAULTS, PARAM_FIELDS
from _servovalve_twin_fmu.physics.sensors import sensors_from_dict
from _servovalve_twin_fmu.physics.simulate import EhaPlant, steps_per

CONFIG = 'eha_fmu.json'
_TYPES = {'float': Real, 'int': Integer, 'bool': Boolean}


class EhaFmu(Fmi2Slave):
    author = 'servovalve_twin'
    description = ('Electro-hydraulic actuator of Dalla Vedova & Alimhillaj (EECS 2018): ECU, '
                   'two-stage servovalve, fluid model, jack')

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        cfg = json.loads((Path(self.resources) / CONFIG).read_text())
        self.valve_model = cfg['valve_model']
        self.control_period = float(cfg['control_period'])
        self._sensors = sensors_from_dict(cfg.get('sensors'))
        self.sensor_seed = self._sensors.seed if self._sensors else 0
        self.com, self.fr, self.psr = 0.0, 0.0, float(DEFAULTS.PSRN)
        self.xj = self.dxj = self.p12 = self.xs = 0.0
        self._plant = None
        # the settable parameters; the derived ones (GM, V0, C4_alpha) derive from these
        self._params = {n: getattr(DEFAULTS, n) for n, f in PARAM_FIELDS.items()
                        if f.default is not None}
        for n in ('com', 'fr', 'psr'):
            self.register_variable(Real(n, causality=Fmi2Causality.input,
                                        variability=Fmi2Variability.discrete))
        for n in ('xj', 'dxj', 'p12', 'xs'):
            self.register_variable(Real(n, causality=Fmi2Causality.output,
                                        variability=Fmi2Variability.continuous))
        self.register_variable(Real('control_period', causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.fixed,
                                    description='ECU sampling period [s], a multiple of DT'))
        if self._sensors:
            self.register_variable(Integer('sensor_seed', causality=Fmi2Causality.parameter,
                                           variability=Fmi2Variability.fixed,
                                           description="the sensors' noise realisation"))
        for n, value in self._params.items():
            meta = PARAM_FIELDS[n].metadata
            self.register_variable(_TYPES[meta['kind']](
                n, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                description=f'{meta["doc"]} [{meta["unit"]}]',
                getter=lambda n=n: self._params[n],
                setter=lambda v, n=n: self._params.__setitem__(n, v)))

    def to_xml(self, model_options=None):
        """pythonfmu's description, with the outputs also listed as InitialUnknowns: they are
        calculated at initialisation (FMI 2.0 section 2.2.8; FMPy's validate_fmu asks)."""
        root = super().to_xml(model_options or {})
        structure = root.find('ModelStructure')
        outputs = structure.find('Outputs')
        if outputs is not None and structure.find('InitialUnknowns') is None:
            initial = SubElement(structure, 'InitialUnknowns')
            for unknown in outputs:
                SubElement(initial, 'Unknown', attrib=dict(index=unknown.get('index')))
        return root

    def exit_initialization_mode(self):
        try:
            params = DEFAULTS.replace(**self._params)
            self._n_sub = steps_per(self.control_period, params, 'control_period')
            self._plant = EhaPlant(self.valve_model, params)
            if self._sensors:
                self._plant.set_sensors(self._sensors.with_seed(int(self.sensor_seed)),
                                        self.control_period)
        except TwinError as exc:
            self.log(str(exc))
            raise
        self._t_ns = 0          # the plant's time: the sensors sample on its grid
        self._outputs()

    def do_step(self, current_time, step_size):
        periods = round(step_size / self.control_period)
        if periods < 1 or abs(step_size - periods * self.control_period) > 1e-9 * step_size:
            # an error, not a discard: a master that took a discard for a shorter step would
            # get outputs that no whole control period produced
            raise ValueError(f'step {step_size} s is not a whole number of control periods '
                             f'({self.control_period} s)')
        plant = self._plant
        sensed = plant.sensors is not None
        for _ in range(periods):
            xj = plant.sense_state(self._t_ns)[1] if sensed else plant.xj
            cor = plant.control(self.com, xj)
            plant.tick(cor, self.fr, self.psr, self._n_sub)
            if sensed:                  # P12 at the period's start: a sample may fall there
                plant.sense_valve(self._t_ns)
            self._t_ns += self._n_sub * plant.params.dt_ns
        self._outputs()
        return True

    def _outputs(self):
        plant = self._plant
        self.xj, self.dxj, self.xs = plant.xj, plant.dxj, plant.xs
        # the valve's answer at the new state to the supply of the step just taken
        response = plant.response(self.fr, self.psr)
        self.p12 = float(response[0])
        if plant.sensors is not None:
            # what the sensors read at the step's end (the next step's first period reads the
            # state again at that instant: the same sample)
            self.xs, self.xj, self.dxj = plant.sense_state(self._t_ns).tolist()
            plant.last[:] = response
            self.p12 = float(plant.sense_valve(self._t_ns)[0])
