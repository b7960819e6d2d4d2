"""The one YAML loader: certificates, the daemon configuration and bench scenarios.

Safe YAML (PyYAML's safe loader: libyaml's C parser where PyYAML was built with it, the same
safe constructors either way) with two rules every file kind shares:

- a duplicated key is an error naming both lines (PyYAML would keep the last
  value silently: a second ``bias: [0, 0, 0]`` would zero the biases);
- a file over :data:`MAX_BYTES` is refused before it is read (a 200 MB
  certificate took a minute and 650 MB to parse, longer than the watchdog;
  the daemon also reads a certificate on SIGHUP in a thread of its own).

Mappings come back as :class:`LineDict`, which remembers the line of each key,
so the callers' errors can name file, line and key path. Errors are
:class:`YamlError` with a one-line message.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from .errors import BadInput

#: Largest YAML file read, bytes (certificates, configurations and scenarios are a few
#: KiB; PyYAML needs about 2 s for 256 KiB of keys, so even that never reaches the loop)
MAX_BYTES = 256 * 1024


class YamlError(BadInput):
    """A YAML file that cannot be used: ``line`` (1-based, or None) and a one-line ``problem``."""

    def __init__(self, problem: str, line: int | None = None) -> None:
        self.problem = " ".join(str(problem).split())
        self.line = line
        where = f"line {line}: " if line is not None else ""
        super().__init__(f"{where}{self.problem}")


class LineDict(dict):
    """A mapping that remembers its own line and the line of each key (1-based)."""

    line: int | None = None
    key_lines: dict[Any, int]


#: libyaml's parser (``yaml.CSafeLoader``) where PyYAML has it: the same documents, marks
#: and safe constructors as the pure-Python ``SafeLoader``, about 6x faster (a certificate:
#: 1.4 ms against 8.7 ms on the 2-core machine; the daemon, each command and the tests
#: load them often)
_BASE: type[yaml.SafeLoader] = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _Loader(_BASE):  # type: ignore[valid-type,misc]
    pass


def _construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode) -> LineDict:
    out = LineDict()
    out.line = node.start_mark.line + 1
    out.key_lines = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        line = key_node.start_mark.line + 1
        if key in out.key_lines:
            raise yaml.constructor.ConstructorError(
                None,
                None,
                f"duplicate key {key!r} (first on line {out.key_lines[key]})",
                key_node.start_mark,
            )
        out.key_lines[key] = line
        out[key] = loader.construct_object(value_node, deep=True)
    return out


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def parse(text: str) -> Any:
    """Parse YAML text; YamlError (with the line) on bad YAML or a duplicated key."""
    if len(text) > MAX_BYTES:
        raise YamlError(f"larger than {MAX_BYTES} bytes: refused")
    try:
        return yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc)
        raise YamlError(
            f"not valid YAML: {problem}", None if mark is None else mark.line + 1
        ) from None
    except (ValueError, OverflowError, RecursionError) as exc:
        # a value YAML cannot build, e.g. the date 2026-13-01
        raise YamlError(f"not valid YAML: {exc}") from None


def read_text(path: str | Path) -> str:
    """The file's text (UTF-8), refused before reading when over :data:`MAX_BYTES`.

    OSError when it cannot be read; YamlError when too large or not UTF-8.
    """
    p = Path(path)
    with open(p, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        if size > MAX_BYTES:
            raise YamlError(f"{size} bytes, larger than the {MAX_BYTES} a YAML file may have")
        data = fh.read(MAX_BYTES + 1)
    if len(data) > MAX_BYTES:  # a file that grew, or a pipe
        raise YamlError(f"larger than the {MAX_BYTES} bytes a YAML file may have")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise YamlError(f"not UTF-8 text: {exc}") from None
