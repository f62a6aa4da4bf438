"""The twin: every node in one executor on simulated time, in deterministic lockstep
(:mod:`.lockstep`), and its executable (:mod:`.executable`)."""

from .lockstep import Twin, TwinResult, run_twin

__all__ = ['Twin', 'TwinResult', 'run_twin']
