"""EHA parameters: one frozen dataclass, SI units, declared bounds, derived values computed.

Each field carries its unit, bounds and meaning in ``metadata``; the same schema feeds the YAML
loader (``config/eha.yaml``), the ``--param NAME=VALUE`` parser, the ROS parameter declarations
and the docs' reference table. Names are the canonical names of doc/design/MODELS.md section 5.

Derived parameters (``GM``, ``V0``, ``C4_alpha``, ``XSS``, ``GPQ``) default to ``None`` and are
computed from the others by :meth:`EhaParams.value`; giving a value overrides the derivation (a
fault may scale ``GM``, for instance). ``XSS`` and ``GPQ``, the simplified models' gains, are
the HD calibration of the design (:func:`servovalve_twin.physics.valves.calibration.calibrate`,
15 ms, cached per HD geometry and supply: :data:`HD_INPUTS`): a design of another geometry or
supply gets its own, never the default design's (kept constants of the default design made a
healthy unit of a larger actuator read as a 0.147 gain loss).
"""

from __future__ import annotations

import collections
import dataclasses
import math
from typing import Any, Mapping

import numpy as np

from ..errors import ParameterError, TwinError


#: the actuator's subsystems that read parameters, as the ROS graph splits them: a node declares
#: exactly the parameters its subsystem reads, and a fault on a parameter goes to its readers
SUBSYSTEMS = ('ecu', 'plant')


def _p(default, unit: str, lo: float, hi: float, doc: str, *, lo_open: bool = False,
       kind: str = 'float', group: str = '', readers: tuple[str, ...] = ('plant',)) -> Any:
    return dataclasses.field(default=default, metadata=dict(
        unit=unit, lo=lo, hi=hi, lo_open=lo_open, doc=doc, kind=kind, group=group,
        readers=readers))


#: the derived parameters (None: derived from the others) and the property that resolves each
DERIVED = {'GM': 'gm', 'V0': 'v0', 'C4_alpha': 'c4_alpha', 'XSS': 'xss', 'GPQ': 'gpq'}


@dataclasses.dataclass(frozen=True)
class EhaParams:
    """All parameters of the EHA plant, its valve models and the integrator (SI units)."""

    # supply
    PSRN: float = _p(20.0e6, 'Pa', 1.0e5, 1.0e8, 'nominal supply-return pressure PS - PR',
                     group='supply')
    PR: float = _p(0.1e6, 'Pa abs', 0.0, 1.0e7, 'return pressure (absolute)', group='supply')
    Pcav: float = _p(0.0, 'Pa abs', 0.0, 1.0e6, 'cavitation floor of a port pressure (HD)',
                     group='supply')
    CLk: float = _p(2.0e-13, 'm^3/(s*Pa)', 0.0, 1.0e-9,
                    'port-to-port leakage coefficient, QLk = CLk*P12', group='supply')
    PSR_scale: float = _p(1.0, '-', 0.0, 1.0, 'fraction of the scheduled PSR that reaches the '
                          'valve (1 = healthy; the supply_loss fault lowers it)', lo_open=True,
                          group='supply')
    # jack
    AJ: float = _p(7.05e-4, 'm^2', 1.0e-6, 1.0, 'jack piston area', lo_open=True, group='jack')
    M: float = _p(500.0, 'kg', 1.0e-3, 1.0e6, 'equivalent moving mass', group='jack')
    CJ: float = _p(2000.0, 'N*s/m', 0.0, 1.0e8, 'viscous friction coefficient', group='jack')
    FDJ: float = _p(200.0, 'N', 0.0, 1.0e7, 'dynamic Coulomb friction', group='jack')
    FSJ: float = _p(300.0, 'N', 0.0, 1.0e7, 'static Coulomb friction (>= FDJ)', group='jack')
    XJM: float = _p(0.1, 'm', 0.0, 10.0, 'jack end stops at +-XJM', lo_open=True, group='jack')
    # ECU
    GAP: float = _p(1.69, 'A/m', 0.0, 1.0e6, 'position-loop gain', lo_open=True, group='ecu',
                    readers=('ecu',))
    # CorM is read by the plant too: the torque-motor gain GM derives from it (KFB*XSM/CorM)
    CorM: float = _p(0.01, 'A', 0.0, 10.0, 'servovalve current saturation', lo_open=True,
                     group='ecu', readers=('ecu', 'plant'))
    CorB: float = _p(0.0, 'A', -10.0, 10.0, 'valve null bias current (fault), added after '
                     'the ECU saturation, in the torque motor', group='servovalve')
    # servovalve mechanics
    GM: float | None = _p(None, 'N/A', 0.0, 1.0e6, 'torque-motor gain; derived KFB*XSM/CorM',
                          lo_open=True, group='servovalve')
    MF: float = _p(1.2e-4, 'kg', 1.0e-9, 1.0, 'first-stage (flapper) mass', group='servovalve')
    CF: float = _p(0.6, 'N*s/m', 0.0, 1.0e4, 'first-stage damping', group='servovalve')
    KF: float = _p(2000.0, 'N/m', 0.0, 1.0e7, 'first-stage stiffness', group='servovalve')
    KFB: float = _p(1000.0, 'N/m', 0.0, 1.0e7, 'feedback-spring stiffness', lo_open=True,
                    group='servovalve')
    XFM: float = _p(3.0e-5, 'm', 0.0, 1.0e-2, 'flapper end of travel', lo_open=True,
                    group='servovalve')
    GQF_AS: float = _p(1200.0, '1/s', 0.0, 1.0e6, 'first-stage flow gain over spool area',
                       lo_open=True, group='servovalve')
    XSM: float = _p(1.5e-4, 'm', 0.0, 1.0e-2, 'spool end of travel', lo_open=True,
                    group='servovalve')
    # HD valve geometry and fluid
    w: float = _p(1.2e-2, 'm', 0.0, 1.0, 'port width (per edge)', lo_open=True, group='hd')
    c: float = _p(7.0e-6, 'm', 0.0, 1.0e-3, 'radial clearance', lo_open=True, group='hd')
    r: float = _p(0.0, 'm', 0.0, 1.0e-3, 'land corner radius', group='hd')
    L_S1: float = _p(0.0, 'm', -1.0e-3, 1.0e-3, 'lap of edge supply->1 (>0 overlap)', group='hd')
    L_1R: float = _p(0.0, 'm', -1.0e-3, 1.0e-3, 'lap of edge 1->return', group='hd')
    L_S2: float = _p(0.0, 'm', -1.0e-3, 1.0e-3, 'lap of edge supply->2', group='hd')
    L_2R: float = _p(0.0, 'm', -1.0e-3, 1.0e-3, 'lap of edge 2->return', group='hd')
    Cd: float = _p(0.61, '-', 0.0, 1.0, 'orifice discharge coefficient', lo_open=True,
                   group='hd')
    rho: float = _p(850.0, 'kg/m^3', 1.0, 1.0e4, 'fluid density', group='hd')
    mu: float = _p(0.0119, 'Pa*s', 0.0, 10.0, 'dynamic viscosity', lo_open=True, group='hd')
    compressible: bool = _p(False, '-', 0, 1, 'HD: port pressures as states (bulk modulus)',
                            kind='bool', group='hd')
    beta: float = _p(1.2e9, 'Pa', 1.0e6, 1.0e11, 'bulk modulus (compressible HD only)',
                     group='hd')
    V0: float | None = _p(None, 'm^3', 0.0, 10.0, 'chamber volume at XJ = 0; derived '
                          'AJ*XJM + 2e-5', lo_open=True, group='hd')
    # simplified models (the HD calibration, see hd.calibrate)
    XSS: float | None = _p(None, 'm', 0.0, 1.0e-2, 'XS at which zero-flow P12 reaches PSR; '
                           "derived: HD's calibration of the design", lo_open=True,
                           group='simplified')
    GPQ: float | None = _p(None, 'Pa*s/m^3', 0.0, 1.0e16, 'pressure-flow gain GP/GQ; derived: '
                           "HD's calibration of the design", lo_open=True, group='simplified')
    C4_alpha: float | None = _p(None, '-', 0.0, 2.0, 'C4 relaxation factor; derived 1/(1+k)',
                                lo_open=True, group='simplified')
    C4_tol: float = _p(1.0e-3, 'Pa', 0.0, 1.0e6, 'C4 convergence tolerance on |dP12|',
                       lo_open=True, group='simplified')
    C4_max_iter: int = _p(200, '-', 1, 1000000, 'C4 iteration cap per step', kind='int',
                          group='simplified')
    # numerics
    DT: float = _p(1.0e-5, 's', 1.0e-9, 1.0e-3, 'fixed integration step (whole nanoseconds)',
                   group='numerics')

    def __post_init__(self):
        for f in dataclasses.fields(self):
            _check_field(f, getattr(self, f.name))
        self._check_cross()

    # -- derived values -------------------------------------------------------------------
    @property
    def gm(self) -> float:
        """Torque-motor gain [N/A]: full current gives full stroke unless GM is given."""
        return self.GM if self.GM is not None else self.KFB * self.XSM / self.CorM

    @property
    def v0(self) -> float:
        """Chamber volume at mid stroke [m^3] (compressible HD)."""
        return self.V0 if self.V0 is not None else self.AJ * self.XJM + 2.0e-5

    @property
    def xss(self) -> float:
        """XSS [m]: the given one, else HD's calibration of this design."""
        return self.XSS if self.XSS is not None else hd_constants(self)[0]

    @property
    def gpq(self) -> float:
        """GPQ [Pa*s/m^3]: the given one, else HD's calibration of this design."""
        return self.GPQ if self.GPQ is not None else hd_constants(self)[1]

    @property
    def gpn(self) -> float:
        """Nominal pressure gain GPN = PSRN/XSS [Pa/m]."""
        return self.PSRN / self.xss

    @property
    def k(self) -> float:
        """Leakage-loop gain k = CLk*GPQ [-]."""
        return self.CLk * self.gpq

    @property
    def c4_alpha(self) -> float:
        """C4 relaxation factor; 1/(1+k) makes the short run converge in one step when linear."""
        return self.C4_alpha if self.C4_alpha is not None else 1.0 / (1.0 + self.k)

    @property
    def dt_ns(self) -> int:
        """The step in integer nanoseconds: simulated time is counted in these."""
        return int(round(self.DT * 1e9))

    def value(self, name: str) -> Any:
        """A parameter's effective value, derived ones resolved."""
        if name not in PARAM_NAMES:
            raise ParameterError(f'unknown parameter {name!r}; expected one of '
                                 f'{sorted(PARAM_NAMES, key=str.lower)}')
        return getattr(self, DERIVED.get(name, name))

    def derived_again(self) -> 'EhaParams':
        """A copy in which each derived parameter that is given but equals its derivation
        from the others is left to derive again -- so that a change of what it derives from
        derives it anew. A record of every parameter resolved (a bag's provenance) gives them
        all: a leak's CLk x 50 on such a design kept C4_alpha at the healthy 1/(1+k), beyond
        the C4 run's limit, and a flight calibration of the shipped example stopped there. A
        value that differs from its derivation was chosen, and stays."""
        given = {n: getattr(self, n) for n in DERIVED if getattr(self, n) is not None}
        if not given:
            return self
        free = self.replace(**{n: None for n in given})
        keep = {n: v for n, v in given.items()
                if not math.isclose(free.value(n), v, rel_tol=1e-9, abs_tol=0.0)}
        return free.replace(**keep) if keep else free

    def resolved(self) -> dict[str, Any]:
        """Every parameter by name with derived values filled in (provenance, ROS, docs)."""
        return {name: self.value(name) for name in PARAM_NAMES}

    def replace(self, **changes: Any) -> 'EhaParams':
        """A copy with ``changes`` applied and validated (names checked first)."""
        unknown = [n for n in changes if n not in PARAM_NAMES]
        if unknown:
            raise ParameterError(f'unknown parameter {unknown[0]!r}; expected one of '
                                 f'{sorted(PARAM_NAMES, key=str.lower)}')
        values = {n: coerce(n, v) for n, v in changes.items()}
        # the unchanged fields were checked when this instance was made: only the changed
        # ones and the cross checks are run again (checking all 41 fields on every replace
        # took 0.09 s of a 2 s diagnosis: a fit makes a parameter set per model run)
        for n, v in values.items():
            _check_field(PARAM_FIELDS[n], v)
        new = object.__new__(type(self))
        new.__dict__.update({n: v for n, v in self.__dict__.items() if n in PARAM_FIELDS},
                            **values)             # not this instance's kernel arrays
        new._check_cross()
        return new

    def kernel(self, constants: tuple[float, ...] = ()) -> 'KernelParams':
        """The flat, all-float tuple that the compiled physics reads (derived values resolved).

        ``constants`` fill the valve-model slots ``VC0``... (zero otherwise): a model's own
        derived constants, computed once by its registry entry
        (:meth:`~.valves.ValveModel.kernel`) rather than every step."""
        if len(constants) > N_VALVE_CONSTANTS:
            raise ParameterError(f'a valve model may define at most {N_VALVE_CONSTANTS} '
                                 f'constants, got {len(constants)}')
        vals = {n: float(v) for n, v in self.resolved().items()}
        vc = [float(c) for c in constants] + [0.0] * (N_VALVE_CONSTANTS - len(constants))
        return KernelParams(**vals, GPN=self.gpn, k=self.k,
                            **{f'VC{i}': c for i, c in enumerate(vc)})

    def kernel_array(self, constants: tuple[float, ...] = ()) -> np.ndarray:
        """The same values as a one-element structured array: numba unboxes it in about 0.3 us
        against 2.5 us for the named tuple, which matters once per ROS tick.

        Built once per parameter set and constants (20 us: 1 % of a 1 s C2 run) and kept on
        this instance -- not in a cache keyed by equality, where 0.0 and -0.0 compare equal
        but are different bits in the physics. Each call returns a copy of its own."""
        cache = self.__dict__.get('_kernel_arrays')
        if cache is None:
            cache = {}
            object.__setattr__(self, '_kernel_arrays', cache)   # frozen: not a field
        key = tuple(float(c).hex() for c in constants)
        if key not in cache:
            cache[key] = kernel_as_array(self.kernel(constants))
        return stack_kernels([cache[key]])

    def _check_cross(self):
        if self.FDJ > self.FSJ:
            raise ParameterError(f'FDJ = {self.FDJ} N exceeds FSJ = {self.FSJ} N; the dynamic '
                                 'friction must not exceed the static friction')
        if self.Pcav > self.PR:
            raise ParameterError(f'Pcav = {self.Pcav} Pa exceeds PR = {self.PR} Pa; the '
                                 'cavitation floor must be at or below the return pressure')
        if abs(self.DT * 1e9 - round(self.DT * 1e9)) > 1e-6:
            raise ParameterError(f'DT = {self.DT} s is not a whole number of nanoseconds; '
                                 'simulated time is counted in integer nanoseconds')
        if self.v0 <= self.AJ * self.XJM:
            raise ParameterError(f'V0 = {self.v0} m^3 must exceed AJ*XJM = '
                                 f'{self.AJ * self.XJM} m^3 (a chamber volume stays positive)')
        if self.c4_alpha >= 2.0 / (1.0 + self.k):
            raise ParameterError(f'C4_alpha = {self.c4_alpha} must be below 2/(1+k) = '
                                 f'{2.0 / (1.0 + self.k):.6g} for the C4 short run to converge')


PARAM_FIELDS = {f.name: f for f in dataclasses.fields(EhaParams)}
PARAM_NAMES = tuple(PARAM_FIELDS)

#: what HD's calibration of XSS and GPQ depends on: the valve's geometry and fluid (the 'hd'
#: group but for the compressible option and its bulk modulus and volume, which a static
#: curve does not see), the spool's travel and the supply
HD_INPUTS = tuple(n for n, f in PARAM_FIELDS.items()
                  if f.metadata['group'] == 'hd' and n not in ('compressible', 'beta', 'V0')
                  ) + ('XSM', 'PSRN', 'PR', 'Pcav')
#: HD's calibration per design (the values of HD_INPUTS) -> (XSS, GPQ). The default design's
#: is the one calibrate() gave once, kept to its last bit so that every default run stays the
#: run it was (calibrate() today gives the same to 1 ulp; test_hd holds them to 1e-9)
_HD_CONSTANTS: dict[tuple, tuple[float, float]] = {}
_DEFAULT_HD_CONSTANTS = (1.7394471845895356e-05, 1.0340455749992211e+12)


def _hd_key(p: 'EhaParams') -> tuple:
    return tuple(float(p.value(n)) if n != 'Pcav' else float(p.Pcav) for n in HD_INPUTS)


#: the function that computes (XSS, GPQ) of a design from HD: physics.valves.calibration, which
#: solves HD -- a module above this one, so it registers itself here (physics/__init__ imports
#: it) rather than being imported from here (that was a circle: params -> calibration -> hd ->
#: params)
_HD_CALIBRATION: list = []


def register_hd_calibration(fn) -> None:
    """Set the function ``fn(params) -> (XSS, GPQ)`` that derives the simplified models' gains
    of a design (:func:`.valves.calibration.hd_gains`)."""
    _HD_CALIBRATION[:] = [fn]


def hd_constants(p: 'EhaParams') -> tuple[float, float]:
    """(XSS, GPQ) of ``p``'s design: HD's calibration, computed once per design."""
    key = _hd_key(p)
    got = _HD_CONSTANTS.get(key)
    if got is None:
        if not _HD_CALIBRATION:
            raise ParameterError('XSS and GPQ are derived from HD, whose calibration is not '
                                 'loaded (import servovalve_twin.physics); or give them')
        try:
            got = _HD_CALIBRATION[0](p)
        except TwinError as exc:
            raise ParameterError(f'XSS and GPQ cannot be derived for this design ({exc}); give '
                                 'them: --param XSS=... --param GPQ=...') from None
        if len(_HD_CONSTANTS) > 256:
            _HD_CONSTANTS.clear()
        _HD_CONSTANTS[key] = got
    return got

# derived constants the compiled models read: the paper's GPN = PSRN/XSS and k = CLk*GPQ, and
# N_VALVE_CONSTANTS slots VC0.. that a valve model fills with its own (its registry entry's
# ``constants``), computed once instead of every step
N_VALVE_CONSTANTS = 2
KernelParams = collections.namedtuple('KernelParams', PARAM_NAMES + ('GPN', 'k') + tuple(
    f'VC{i}' for i in range(N_VALVE_CONSTANTS)))
KernelParams.__doc__ = 'All-float parameter tuple read by the compiled physics.'
KERNEL_DTYPE = np.dtype([(n, np.float64) for n in KernelParams._fields])


def kernel_as_array(kernel: 'KernelParams') -> np.ndarray:
    """A kernel tuple as the one-element structured array the compiled loops take (for a
    caller that keeps both, as the progpy model does per parameter set)."""
    return np.array([tuple(kernel)], dtype=KERNEL_DTYPE)


def stack_kernels(rows: list[np.ndarray]) -> np.ndarray:
    """Kernel arrays stacked into one new array (a copy, even of one row). Every field is a
    float64, so the rows are copied as plain doubles: numpy copies a structured array of 45
    fields field by field (11 us for one row, against 1 us)."""
    return np.concatenate([r.view(np.float64) for r in rows]).view(KERNEL_DTYPE)


def coerce(name: str, value: Any) -> Any:
    """Turn a user-given value (number, or string from a CLI or a YAML 1.1 file) into the
    parameter's type, or raise :class:`ParameterError` naming it.

    PyYAML reads ``20.0e6`` as a *string* (YAML 1.1 floats need a dot and a signed exponent), so
    strings are parsed here rather than passed on.
    """
    if name not in PARAM_FIELDS:
        raise ParameterError(f'unknown parameter {name!r}; expected one of '
                             f'{sorted(PARAM_NAMES, key=str.lower)}')
    meta = PARAM_FIELDS[name].metadata
    if value is None:
        if PARAM_FIELDS[name].default is None:
            return None
        raise ParameterError(f'parameter {name} needs a value')
    if meta['kind'] == 'bool':
        if isinstance(value, bool):
            return value
        text = str(value).strip().lower()
        if text in ('true', '1', 'yes', 'on'):
            return True
        if text in ('false', '0', 'no', 'off'):
            return False
        raise ParameterError(f'parameter {name} must be true or false, got {value!r}')
    if isinstance(value, bool):
        raise ParameterError(f'parameter {name} must be a number, got {value!r}')
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f'parameter {name} must be a number [{meta["unit"]}], '
                             f'got {value!r}') from None
    if meta['kind'] == 'int':
        if not math.isfinite(number) or number != int(number):
            raise ParameterError(f'parameter {name} must be an integer, got {value!r}')
        return int(number)
    return number


def _check_field(f: dataclasses.Field, value: Any) -> None:
    meta = f.metadata
    if value is None and f.default is None:
        return
    if meta['kind'] == 'bool':
        if not isinstance(value, bool):
            raise ParameterError(f'parameter {f.name} must be true or false, got {value!r}')
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f'parameter {f.name} must be a number, got {value!r}')
    if not math.isfinite(value):
        raise ParameterError(f'parameter {f.name} must be finite, got {value!r}')
    lo, hi = meta['lo'], meta['hi']
    below = value <= lo if meta['lo_open'] else value < lo
    if below or value > hi:
        left = '(' if meta['lo_open'] else '['
        raise ParameterError(f'parameter {f.name} = {value!r} {meta["unit"]} is out of range; '
                             f'allowed {left}{lo:g}, {hi:g}]')


def make_params(overrides: Mapping[str, Any] | None = None,
                base: EhaParams | None = None) -> EhaParams:
    """``base`` with ``overrides`` (name -> value, strings accepted) applied and validated."""
    return (base or DEFAULTS).replace(**dict(overrides or {}))


def parse_assignments(items: list[str] | None) -> dict[str, Any]:
    """Parse ``NAME=VALUE`` strings of the command line into coerced values."""
    out: dict[str, Any] = {}
    for item in items or []:
        name, sep, value = item.partition('=')
        name = name.strip()
        if not sep or not name:
            raise ParameterError(f'--param expects NAME=VALUE, got {item!r}')
        out[name] = coerce(name, value.strip())
    return out


def param_table() -> list[dict[str, Any]]:
    """One row per parameter (name, default, unit, bounds, doc): the docs and ROS read this."""
    rows = []
    for name, f in PARAM_FIELDS.items():
        m = f.metadata
        rows.append(dict(name=name, default=DEFAULTS.value(name), unit=m['unit'], lo=m['lo'],
                         hi=m['hi'], lo_open=m['lo_open'], doc=m['doc'], kind=m['kind'],
                         derived=f.default is None, group=m['group'], readers=m['readers']))
    return rows


def names_read_by(subsystem: str) -> tuple[str, ...]:
    """The parameters that ``subsystem`` (one of :data:`SUBSYSTEMS`) reads."""
    if subsystem not in SUBSYSTEMS:
        raise ParameterError(f'unknown subsystem {subsystem!r}; expected one of {SUBSYSTEMS}')
    return tuple(n for n, f in PARAM_FIELDS.items() if subsystem in f.metadata['readers'])


_HD_CONSTANTS[_hd_key(EhaParams(XSS=_DEFAULT_HD_CONSTANTS[0], GPQ=_DEFAULT_HD_CONSTANTS[1]))
              ] = _DEFAULT_HD_CONSTANTS
DEFAULTS = EhaParams()
