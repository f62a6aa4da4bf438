"""``.. twin-table:: NAME``: the reference tables built from the code's own tables when the docs
are built -- never kept by hand. NAME is one of :data:`TABLES`."""

from __future__ import annotations

from docutils import nodes
from docutils.parsers.rst import Directive


def _params():
    from servovalve_twin.physics.params import param_table
    rows = []
    for r in param_table():
        bounds = f'{"(" if r["lo_open"] else "["}{r["lo"]:g}, {r["hi"]:g}]'
        rows.append([r['name'], f'{r["default"]:g}' if isinstance(r['default'], float)
                     else str(r['default']), r['unit'], bounds,
                     ', '.join(r['readers']), r['doc'] + (' (derived)' if r['derived'] else '')])
    return ['name', 'default', 'unit', 'bounds', 'read by', 'meaning'], rows


def _faults():
    from servovalve_twin.physics.faults import FAULTS
    from servovalve_twin.prognostics.diagnosis import DIAGNOSABLE
    return (['fault', 'parameter', 'kind', 'range', 'alarm', 'a diagnosis hypothesis', 'meaning'],
            [[f.name, f.param, f.kind, f'[{f.lo:g}, {f.hi:g}] {f.unit}', f'{f.demo:g}',
              'yes' if f.name in DIAGNOSABLE else 'no (HD geometry)', f.meaning]
             for f in FAULTS.values()])


def _valve_models():
    from servovalve_twin.physics.valves import VALVE_MODELS
    return (['model', 'summary', 'port pressures', 'iterative', 'monitor model'],
            [[m.name, m.summary, 'yes' if m.has_ports else 'no', 'yes' if m.iterative else 'no',
              'yes' if m.monitor else 'no'] for m in VALVE_MODELS.values()])


def _topics():
    from servovalve_twin.nodes.topics import TOPICS
    return (['topic', 'type', 'unit', 'publisher', 'meaning'],
            [[name, f'{t.__module__.split(".")[0]}/msg/{t.__name__}', unit, pub, meaning]
             for name, (t, unit, pub, meaning) in TOPICS.items()])


def _storages():
    from servovalve_twin.bag.storages import STORAGES
    return (['storage', 'file suffix', 'reader'],
            [[s.name, s.suffix, (type(s).__doc__ or '').strip().split('\n')[0]]
             for s in STORAGES.values()])


TABLES = {'params': _params, 'faults': _faults, 'valve-models': _valve_models,
          'topics': _topics, 'storages': _storages}


class TwinTable(Directive):
    required_arguments = 1

    def run(self):
        name = self.arguments[0]
        if name not in TABLES:
            raise self.error(f'unknown twin-table {name!r}; expected one of {sorted(TABLES)}')
        header, rows = TABLES[name]()
        table = nodes.table()
        group = nodes.tgroup(cols=len(header))
        table += group
        for _ in header:
            group += nodes.colspec(colwidth=1)
        head = nodes.thead()
        group += head
        head += self._row(header)
        body = nodes.tbody()
        group += body
        for r in rows:
            body += self._row(r)
        return [table]

    @staticmethod
    def _row(cells):
        row = nodes.row()
        for c in cells:
            entry = nodes.entry()
            entry += nodes.paragraph(text=str(c))
            row += entry
        return row


def setup(app):
    app.add_directive('twin-table', TwinTable)
    return {'parallel_read_safe': True}
