"""YAML text -> its data and its node tree (line numbers for messages), parsed by libyaml where PyYAML has it (about
15x faster than the Python parser: a replay's start reads two YAML files); a YAML error is raised by the Python
parser, so its wording does not depend on the installation."""
from __future__ import annotations

import yaml

_FAST = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def load_with_nodes(text: str):
    """(yaml.safe_load(text), yaml.compose(text)), the data constructed from the one node tree parsed;
    yaml.YAMLError (the Python parser's) on invalid YAML."""
    loader = _FAST(text)
    try:
        root = loader.get_single_node()
        return (None if root is None else loader.construct_document(root)), root
    except yaml.YAMLError:
        if _FAST is yaml.SafeLoader:
            raise
    finally:
        loader.dispose()
    return yaml.safe_load(text), yaml.compose(text)
