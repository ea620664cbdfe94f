"""Frozen dataclasses written to and read from JSON mappings field by field: the typed records of a
solution file (output/solution_records.py) and the motion-limit report (model/limits/report.py).

Here, below both layers, so that a record of the model layer is written as the output layer's are:
an optional field (default None) left at None is no key, a nested record is its own mapping, and
reading a mapping with a key the record does not know is a ValueError (nothing dropped unread).
"""

from __future__ import annotations

from dataclasses import fields


def put_fields(obj, d: dict) -> dict:
    """Write the fields of a record into `d` under their own names; an optional field (default
    None) left at None is not written, a nested record is written as its mapping."""
    for f in fields(obj):
        v = getattr(obj, f.name)
        if v is None and f.default is None:
            continue
        if hasattr(v, "to_json"):
            v = v.to_json()
        elif isinstance(v, list):
            v = [x.to_json() if hasattr(x, "to_json") else x for x in v]
        d[f.name] = v
    return d


def take_fields(cls, d: dict, nested: dict | None = None, whole: bool = False):
    """A record of `cls` from the keys of `d` named like its fields (removed from `d`); `nested`
    maps a field to the function reading its value. `whole`: `d` is the record's own mapping, a
    key it does not know is a ValueError (so nothing of a file is dropped unread)."""
    nested = nested or {}
    kw = {}
    for f in fields(cls):
        if f.name in d:
            v = d.pop(f.name)
            kw[f.name] = v if v is None or f.name not in nested else nested[f.name](v)
    if whole and d:
        raise ValueError(f"{cls.__name__}: unknown keys {sorted(d)}")
    return cls(**kw)


class JsonRecord:
    """A record written as a mapping of its own (`to_json`, `from_json`)."""

    @staticmethod
    def _readers() -> dict:
        """Field name -> the function reading its value from the file (nested records)."""
        return {}

    def to_json(self) -> dict:
        return put_fields(self, {})

    @classmethod
    def from_json(cls, d: dict):
        """The record from its mapping; a key it does not know is a ValueError."""
        return take_fields(cls, dict(d), cls._readers(), whole=True)
