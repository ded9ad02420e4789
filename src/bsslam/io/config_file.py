"""The configuration as a YAML file: the nested sections of :class:`SLAMConfig`.

An empty file is the default configuration; any section or key left out keeps its default.
"""

from __future__ import annotations

import yaml

from bsslam.config import SLAMConfig
from bsslam.errors import ConfigError, InputError
from bsslam.io.path_or_file import PathOrFile, describe, open_path_or_file


def load_config(source: PathOrFile) -> SLAMConfig:
    """Read a YAML configuration.

    Raises:
        ConfigError: missing/unreadable file, invalid YAML, a top level that is not a
            mapping, or an unknown/invalid value; the message names the file.
    """
    name = describe(source)
    try:
        with open_path_or_file(source) as f:
            data = yaml.safe_load(f)
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
        raise ConfigError(f"{name}: {exc}") from None
    except (TypeError, ValueError) as exc:
        # e.g. a string where a number belongs reaches a comparison in __post_init__
        raise ConfigError(f"{name}: invalid value: {exc}") from None


def write_config(target: PathOrFile, config: SLAMConfig) -> None:
    """Write ``config`` as YAML that :func:`load_config` reads back to an equal object."""
    with open_path_or_file(target, "w") as f:
        f.write("# bsslam configuration (units in the key names: _m metres, _rad radians)\n")
        yaml.safe_dump(config.to_dict(), f, sort_keys=False)
