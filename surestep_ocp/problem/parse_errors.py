"""Every error of a problem file's section at once: after its first error a section is read again
with each bad key removed (`more_errors`), until it reads or an error repeats; an error that a
removed key causes is not another one (`_consequence`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..errors import ProblemError


# errors reported per section (each found by reading it again without the last bad key)
MAX_SECTION_ERRORS = 20


def _key_path(key: str | None, section: str) -> list[str]:
    """The mapping keys inside `section` of an error's key path, up to the first list index:
    `goal.pose.position[2]` in `goal` -> [`pose`, `position`]."""
    if not key or not (key == section or key.startswith(section + ".")
                       or key.startswith(section + "[")):
        return []
    out = []
    for part in key[len(section):].lstrip(".").split("."):
        if not part:
            break
        name = part.split("[")[0]
        if not name:
            break
        out.append(name)
        if "[" in part:
            break
    return out


def more_errors(section: str, node: Any, read, args: tuple, kwargs: dict,
                 first: ProblemError) -> list[ProblemError]:
    """The section's further errors: it is read again with each bad key removed, until it reads or
    an error repeats (a key that was removed and is then missing is not another error)."""
    if not isinstance(node, Mapping):
        return []
    where = next((i for i, a in enumerate(args) if a is node), None)
    if where is None:
        return []
    copy, exc, found, removed = copy_tree(node), first, [], []
    for _ in range(MAX_SECTION_ERRORS - 1):
        path = _key_path(exc.key, section)
        parent = copy
        for name in path[:-1]:
            parent = parent.get(name) if isinstance(parent, Mapping) else None
        if not path or not isinstance(parent, dict) or path[-1] not in parent:
            break
        del parent[path[-1]]
        removed.append(".".join([section, *path]))
        try:
            read(*args[:where], copy, *args[where + 1:], **kwargs)
            break
        except ProblemError as again:
            if _consequence(again.key, removed, section, node) or any(
                    again.key == e.key for e in [first, *found]):
                break  # caused by a removed key, or the same error again
            found.append(again)
            exc = again
    return found


def _consequence(key: str | None, removed: list[str], section: str, node: Any) -> bool:
    """Whether an error at `key` is caused by removing the keys `removed` from `node` (the
    section's tree): the key itself or an ancestor of one (reported missing, or `give exactly one
    of`), or a sibling of one that `node` does not have, which the removed key stood for
    (`pose.matrix` removed: `pose.position` missing)."""
    key = key or ""
    if any(r == key or r.startswith(key + ".") for r in removed):
        return True
    parent = key.rsplit(".", 1)[0]
    if not any(r.rsplit(".", 1)[0] == parent for r in removed):
        return False
    path = _key_path(key, section)
    for name in path:
        if not isinstance(node, Mapping) or name not in node:
            return True
        node = node[name]
    return False


def copy_tree(node: Any) -> Any:
    """A copy of a YAML tree's mappings and lists (the leaves shared)."""
    if isinstance(node, Mapping):
        return {k: copy_tree(v) for k, v in node.items()}
    if isinstance(node, list):
        return [copy_tree(v) for v in node]
    return node
