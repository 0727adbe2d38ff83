"""YAML text -> its data and its node tree (line numbers for messages), parsed by libyaml where PyYAML has it (about
15x faster than the Python parser: a replay's start reads two YAML files); a YAML error is raised by the Python
parser, so its wording does not depend on the installation."""
from __future__ import annotations

import yaml

_FAST = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def load_with_nodes(text: str):
    """(yaml.safe_load(text), yaml.compose(text)); yaml.YAMLError (the Python parser's) on invalid YAML."""
    try:
        return yaml.load(text, Loader=_FAST), yaml.compose(text, Loader=_FAST)
    except yaml.YAMLError:
        if _FAST is yaml.SafeLoader:
            raise
    return yaml.safe_load(text), yaml.compose(text)
