"""A user's detector, written as a plain Python class: internal leakage of the servovalve from
the opening it needs to hold a load.

Holding still against a load, a leak-free valve needs only the opening that makes the load
pressure: by the paper's C2 law P12 = (PSR*XS/XSS - GPQ*QJ)/(1 + k) with QJ ~ 0, the opening
ratio R = |XS|*PSR/(|P12|*XSS) is 1 + k. The port-to-port leak CLk*P12 must be supplied through
the valve too, so R grows with the leakage. The index is R smoothed over the holding ticks
(|DXJ| small, |P12| large); it crosses WARN and then ERROR as the leak grows. It knows only the
design value XSS -- nothing of the unit it watches.
"""

from servovalve_twin.prognostics import ERROR, OK, WARN, Algorithm, Health


class LeakDetector(Algorithm):
    inputs = ('xs', 'dxj', 'p12', 'psr')
    outputs = ('leak_index', 'holding')
    parameters = {'warn': 1.7, 'threshold': 1.85, 'tau': 0.05, 'min_hold': 5,
                  'max_speed': 2.0e-3, 'min_p12': 2.0e6}

    def reset(self):
        self.index = 0.0
        self.held = 0
        self.level = OK

    def step(self, t, u):
        p = self.params
        holding = abs(u['dxj']) < p['max_speed'] and abs(u['p12']) > p['min_p12']
        if holding:
            ratio = abs(u['xs']) * u['psr'] / (abs(u['p12']) * self.nominal.xss)
            gain = self.period / p['tau']
            self.index = ratio if self.held == 0 else self.index + gain * (ratio - self.index)
            self.held += 1
        if self.held >= p['min_hold']:
            self.level = (ERROR if self.index > p['threshold']
                          else WARN if self.index > p['warn'] else OK)
        return {'leak_index': self.index, 'holding': float(holding)}

    def health(self):
        return Health(self.level, f'leak index {self.index:.3f} (ERROR above '
                                  f'{self.params["threshold"]:g}) over {self.held} holding ticks',
                      {'leak_index': self.index})
