"""The YAML loaders for every file a user edits (``scan.yaml``, ``params.yaml``, ``--set`` values).

Both are ``yaml.SafeLoader``s (plain YAML types only, never Python objects) that refuse a mapping
which repeats a key (:class:`DuplicateKeyError`: a silent "last one wins" hides mistakes, such as
``samples`` given twice under ``render:``) and read YAML 1.2 floats such as ``3.45e1`` as numbers
(YAML 1.1, PyYAML's default, needs a dot and a signed exponent: ``3.45e+1``), as DVC's reader does.
:class:`SidecarLoader` is pure Python; :class:`StrictLoader` the same rules on libyaml's parser when
PyYAML has it (about 10x faster: the pure-Python one took 27 ms per read of params.yaml).
"""

from __future__ import annotations

import re

import yaml

# YAML 1.2 core-schema floats ("3.45e1", "1e3", ".5"), which YAML 1.1 (PyYAML's default) reads as text
_FLOAT_12 = re.compile(r"""^[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?$
                           |^[-+]?\.(?:inf|Inf|INF)$|^\.(?:nan|NaN|NAN)$""", re.X)


class DuplicateKeyError(yaml.YAMLError):
    """A YAML mapping repeats a key."""

    def __init__(self, key, mark):
        self.key, self.mark = key, mark
        line = f" (line {mark.line + 1})" if mark is not None else ""
        super().__init__(f"duplicate key {key!r}{line}")


class _StrictMappings:
    """Loader mixin: a mapping that repeats a key raises :class:`DuplicateKeyError`."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue                   # "<<: *base" merges; explicit keys may override it
                key = self.construct_object(key_node, deep=True)
                try:
                    new = key not in seen
                except TypeError:          # unhashable key: the base class reports it
                    break
                if not new:
                    raise DuplicateKeyError(key, key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


class SidecarLoader(_StrictMappings, yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate mapping keys and reads YAML 1.2 floats."""


class StrictLoader(_StrictMappings, getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
    """The same rules as :class:`SidecarLoader` on libyaml's parser when PyYAML has it (about 10x
    faster): what ``params.yaml`` and the settings given on a command line are read with."""


for _loader in (SidecarLoader, StrictLoader):
    _loader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+0123456789."))


def load_strict(stream):
    """A YAML text or stream read with :class:`StrictLoader` (params.yaml's rules: safe types
    only, no repeated key, YAML 1.2 numbers)."""
    return yaml.load(stream, Loader=StrictLoader)     # StrictLoader is a SafeLoader
