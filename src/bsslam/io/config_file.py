"""The configuration as a YAML file: the nested sections of :class:`SLAMConfig`.

An empty file is the default configuration; any section or key left out keeps its default.
Numbers are read as YAML 1.2 writes them: ``1e9`` and ``1.0e9`` are floats (PyYAML's YAML 1.1
rules read both as strings).
"""

from __future__ import annotations

import re

import yaml

from bsslam.config import SLAMConfig
from bsslam.errors import ConfigError, InputError
from bsslam.io.path_or_file import PathOrFile, describe, open_path_or_file


_FLOAT_TAG = "tag:yaml.org,2002:float"

# YAML 1.2 core schema floats, plus 1.1's forms that PyYAML already reads (1_000.5, .5)
_YAML12_FLOAT = re.compile(r"""^(?:
     [-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |[-+]?\.[0-9_]+(?:[eE][-+]?[0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X)


class ConfigLoader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2 floats: ``1e9``, ``1.0e9``, ``-2E-3`` are numbers,
    not strings. (The int resolver comes first and matches only plain integers.)"""


ConfigLoader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag != _FLOAT_TAG]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
ConfigLoader.add_implicit_resolver(_FLOAT_TAG, _YAML12_FLOAT, list("-+0123456789."))


def load_config(source: PathOrFile) -> SLAMConfig:
    """Read a YAML configuration.

    The values are typed and checked (:func:`SLAMConfig.from_dict`) here, before any work.

    Raises:
        ConfigError: missing/unreadable file, invalid YAML, a top level that is not a
            mapping, an unknown key, or a value of the wrong type or out of range; the
            message names the file, the line of the value where it is in the file, and
            the key (``section.key``).
    """
    name = describe(source)
    try:
        with open_path_or_file(source) as f:
            loader = ConfigLoader(f)
            try:
                node = loader.get_single_node()    # kept to find the line of a bad value
                data = None if node is None else loader.construct_document(node)
            finally:
                loader.dispose()
    except InputError as exc:
        raise ConfigError(str(exc)) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{name}:{mark.line + 1}" if mark is not None else name
        raise ConfigError(f"{where}: invalid YAML: {getattr(exc, 'problem', None) or exc}") from None
    if data is not None and not isinstance(data, dict):
        raise ConfigError(f"{name}: the configuration must be a mapping of sections, got {type(data).__name__}")
    try:
        return SLAMConfig.from_dict(data)
    except ConfigError as exc:
        line = _line_of_key(node, str(exc))
        raise ConfigError(f"{name}:{line}: {exc}" if line is not None else f"{name}: {exc}") from None
    except (TypeError, ValueError) as exc:
        # e.g. a string where a number belongs reaches a comparison in __post_init__
        raise ConfigError(f"{name}: invalid value: {exc}") from None


# the key a ConfigError's message starts with: "section.key: …", "section.key must …", "key[1]: …"
_MESSAGE_KEY = re.compile(r"^([A-Za-z_]+(?:\.[A-Za-z_]+)?)(?:\[(\d+)\])?[:\s]")


def _line_of_key(node: yaml.Node | None, message: str) -> int | None:
    """The 1-based line of the value the message is about, or None when it names no key
    present in the file (e.g. a check across two keys left at their defaults)."""
    match = _MESSAGE_KEY.match(message)
    if node is None or match is None:
        return None
    where = node
    for part in match.group(1).split("."):
        if not isinstance(node, yaml.MappingNode):
            return None
        pair = next(((key, value) for key, value in node.value if getattr(key, "value", None) == part), None)
        if pair is None:
            return None
        where, node = pair     # the key's line: a section's values start on the next one
    index = match.group(2)
    if index is not None and isinstance(node, yaml.SequenceNode) and int(index) < len(node.value):
        where = node.value[int(index)]
    return where.start_mark.line + 1


def write_config(target: PathOrFile, config: SLAMConfig) -> None:
    """Write ``config`` as YAML that :func:`load_config` reads back to an equal object."""
    with open_path_or_file(target, "w") as f:
        f.write("# bsslam configuration (units in the key names: _m metres, _rad radians)\n")
        yaml.safe_dump(config.to_dict(), f, sort_keys=False)
