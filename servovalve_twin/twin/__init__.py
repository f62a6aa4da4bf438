"""The twin: every node in one executor on simulated time, in deterministic lockstep
(:mod:`.lockstep`), its configuration (:mod:`.config`), its place on the graph -- executor and
/clock (:mod:`.graph`) -- and its executable (:mod:`.executable`).

The names below are loaded on first use: the command line reads :mod:`.config` to build its
options without importing rclpy.
"""

__all__ = ['Twin', 'TwinConfig', 'TwinResult', 'run_twin']


def __getattr__(name: str):
    if name in ('Twin', 'run_twin'):
        from . import lockstep
        return getattr(lockstep, name)
    if name in ('TwinConfig', 'TwinResult'):
        from . import config
        return getattr(config, name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
