"""rosbag2-layout MCAP bags: writing, reading, reindexing, replay."""

import yaml

#: PyYAML's safe loader, in C (libyaml) where the installed PyYAML has it: a bag's
#: metadata.yaml and its topics' QoS strings, parsed by the pure-Python loader, took 0.15 s of
#: a 2.2 s ``diagnose`` (the same documents, the same values: libyaml only scans and parses)
SAFE_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def safe_load(text: str):
    """``yaml.safe_load`` with :data:`SAFE_LOADER`."""
    return yaml.load(text, Loader=SAFE_LOADER)        # noqa: S506 -- a safe loader
