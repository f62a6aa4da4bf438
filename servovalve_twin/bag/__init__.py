"""rosbag2-layout MCAP bags: writing, reading, reindexing, replay."""

import yaml

#: PyYAML's safe loader, in C (libyaml) where the installed PyYAML has it: a bag's
#: metadata.yaml and its topics' QoS strings, parsed by the pure-Python loader, took 0.15 s of
#: a 2.2 s ``diagnose`` (the same documents, the same values: libyaml only scans and parses)
SAFE_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def safe_load(text: str):
    """``yaml.safe_load`` with :data:`SAFE_LOADER`; every way a document can fail to load is
    a ``yaml.YAMLError`` (what its callers turn into one line): nesting deeper than Python's
    recursion (RecursionError) and a value Python refuses to build -- an integer of more than
    4300 digits (ValueError) -- were tracebacks."""
    try:
        return yaml.load(text, Loader=SAFE_LOADER)    # noqa: S506 -- a safe loader
    except RecursionError:
        raise yaml.YAMLError('nested too deeply') from None
    except ValueError as exc:
        raise yaml.YAMLError(f'a value that cannot be read: {str(exc)[:80]}') from None
