"""The twin's small error hierarchy: every error a user can cause is one of these.

The command line turns them into exit code 2 and a one-line message; nodes turn them into
refused parameter sets or a clean start-up failure. Nothing else should reach the user as a
traceback.
"""


class TwinError(Exception):
    """Base class of every error caused by input to the twin (not by a bug in it)."""


class ParameterError(TwinError, ValueError):
    """A physical or numerical parameter is unknown, non-finite or out of its bounds."""


class ModelError(TwinError, ValueError):
    """An unknown valve model name, or a model that failed to compute (e.g. no convergence)."""


class ScenarioError(TwinError, ValueError):
    """A scenario file or dict is malformed: unknown key, bad breakpoint, non-numeric value."""


class BagError(TwinError):
    """A bag directory or MCAP file is missing, truncated, corrupt or not of the twin's layout."""


def one_line(exc: BaseException | str, limit: int = 600) -> str:
    """An error's message as the one line a user is shown, of bounded length (a message may
    hold a parameter file's text or a list of every allowed name)."""
    text = ' '.join(str(exc).split())
    return text[:limit] + ' ...' if len(text) > limit else text


def rcl_refusal(exc: BaseException) -> str | None:
    """rcl's refusal of a command line (a params file that is missing, a -p value YAML cannot
    parse) as the one line a user is shown, None for any other error. Its classes are those
    of the C extension as rclpy loads it (not the module object ``rclpy._rclpy_pybind11``: an
    ``except`` naming that missed them), so known by their module's name -- which also keeps
    this free of importing rclpy."""
    if not isinstance(exc, RuntimeError) or type(exc).__module__ != 'rclpy._rclpy_pybind11':
        return None
    return one_line(str(exc).split(', at ')[0])
