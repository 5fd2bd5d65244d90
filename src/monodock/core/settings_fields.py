"""Reading a settings class from one mapping of a larger file, some of its fields given by the file's structure.

A marker's role (``markers: {left: {...}}``) and a dock's name (``docks: {home: {...}}``) are the keys their
mappings sit under, not keys in them. ``from_fields`` reads the other fields as ``core.settings.from_mapping``
does (each key as its field declares, errors naming the whole key path, unknown keys warned about) from a
``Fields`` that already knows that path.

Interim: this belongs in ``core.settings`` (issue 40); it uses that module's field walk and value reader.
"""

from __future__ import annotations

from dataclasses import MISSING
from typing import Any, TypeVar

from monodock.core import settings
from monodock.core.config import Fields

__all__ = ["from_fields"]

T = TypeVar("T")


def from_fields(cls: type[T], fields: Fields, **given: Any) -> T:
    """An instance of the settings class ``cls``: the ``given`` fields as they are, every other field read from
    ``fields`` (its prefix names the keys in errors); unknown keys are warned about.

    Raises:
        ConfigError: one line naming the file and the key (``layout.yaml: markers.left.y: ...``).
    """
    policy = settings.policy_of(cls)
    declared = [f for f in settings._fields(cls) if f.name not in given]  # interim, see above
    values = dict(given)
    for f in declared:
        key = next((k for k in (f.key, *f.meta.aliases) if fields.has(k)), None)
        if key is None:
            if f.meta.required or f.default is MISSING:
                fields.raw(f.key)  # "missing field"
            continue
        values[f.name] = settings._read_value(fields, key, f, policy)
    fields.warn_unknown([*(f.key for f in declared), *(a for f in declared for a in f.meta.aliases), *policy.ignore])
    return cls(**values)
