"""Reading problem files: the strict YAML loader, its size caps, and the entry points.

`read_yaml` parses a file strictly (duplicate keys rejected, nesting and alias expansion bounded, no
YAML 1.1 base-60 numbers); `load_problem` reads and validates a problem file, `problem_from_dict` a
tree built in Python (both through `spec.parse_problem`).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from ..errors import ProblemError, shown
from .paths import find_shipped
from .spec import Problem, parse_problem, plain_tree

# Limits of what a problem (or evaluation) file may be (problems/README.md, "Limits"); the caps on
# the values it holds are caps.py's.
MAX_FILE_BYTES = 1_000_000
MAX_YAML_DEPTH = 40  # nesting levels
# values in the file, with every alias counted as the size of what it names
MAX_YAML_NODES = 100_000


# libyaml's scanner and parser in C (faster: the fuzz tests read hundreds of files; docs/cli.md,
# "Reading problem files"); the composer stays in Python (it bounds the tree)
try:
    from yaml._yaml import CParser as _Parser
except ImportError:  # pragma: no cover - PyYAML without libyaml
    from yaml.parser import Parser as _Parser
    from yaml.reader import Reader as _YamlReader
    from yaml.scanner import Scanner as _Scanner

    class _Parser(_YamlReader, _Scanner, _Parser):  # type: ignore[no-redef]
        def __init__(self, stream):
            _YamlReader.__init__(self, stream)
            _Scanner.__init__(self)
            _Parser.__init__(self)


class _StrictLoader(yaml.composer.Composer, _Parser, yaml.constructor.SafeConstructor,
                    yaml.resolver.Resolver):
    """A YAML safe loader that rejects a key given twice in one mapping, bounds nesting and alias
    expansion, and reads no YAML 1.1 base-60 numbers (`1:20` is a string, not 80); `1e-3` is a
    number."""

    def __init__(self, stream):
        _Parser.__init__(self, stream)
        yaml.composer.Composer.__init__(self)
        yaml.constructor.SafeConstructor.__init__(self)
        yaml.resolver.Resolver.__init__(self)
        self._depth = 0
        self._nodes = 0
        self._sizes: dict[int, int] = {}

    def compose_node(self, parent, index):
        event = self.peek_event()
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise yaml.composer.ComposerError(None, None,
                                                  f"nested deeper than {MAX_YAML_DEPTH} levels",
                                                  event.start_mark)
            if isinstance(event, yaml.AliasEvent) and event.anchor in self.anchors:
                self._nodes += _yaml_size(self.anchors[event.anchor], self._sizes)
            else:
                self._nodes += 1
            if self._nodes > MAX_YAML_NODES:
                raise yaml.composer.ComposerError(None, None,
                                                  f"more than {MAX_YAML_NODES} values (aliases "
                                                  "counted expanded)", event.start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _yaml_size(node: yaml.Node, memo: dict[int, int]) -> int:
    """Number of values a node stands for once its aliases are expanded."""
    if id(node) not in memo:
        if isinstance(node, yaml.SequenceNode):
            memo[id(node)] = 1 + sum(_yaml_size(n, memo) for n in node.value)
        elif isinstance(node, yaml.MappingNode):
            memo[id(node)] = 1 + sum(_yaml_size(k, memo) + _yaml_size(v, memo)
                                     for k, v in node.value)
        else:
            memo[id(node)] = 1
    return memo[id(node)]


# (verbose patterns: their line breaks and indentation are not part of them)
_INT = re.compile(r"""^(?:[-+]?0b[0-1_]+|[-+]?0[0-7_]+|[-+]?(?:0|[1-9][0-9_]*)
                  |[-+]?0x[0-9a-fA-F_]+)$""", re.VERBOSE)
_FLOAT = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                    |[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+
                    |[-+]?\.[0-9_]+(?:[eE][-+]?[0-9]+)?|[-+]?\.(?:inf|Inf|INF)
                    |\.(?:nan|NaN|NAN))$""", re.VERBOSE)
_StrictLoader.yaml_implicit_resolvers = {
    first: [(tag, _INT if tag.endswith(":int") else _FLOAT if tag.endswith(":float") else rx)
            for tag, rx in rs]
    for first, rs in yaml.SafeLoader.yaml_implicit_resolvers.items()}


def _no_duplicates(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False):
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            hash(key)
        except TypeError:
            raise yaml.constructor.ConstructorError(None, None,
                                                    "a key must be a name, not a list or a mapping",
                                                    key_node.start_mark) from None
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"key '{key}' given twice",
                                                    key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep)


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _no_duplicates)


def load_problem(path: str | Path) -> Problem:
    """Read and validate a problem file.

    Raises:
        ProblemError: naming the file, the key path and what is allowed.
    """
    path = find_shipped(path)
    return parse_problem(read_yaml(path), path)



MINIMAL_PROBLEM = {
    # the shipped dVRK PSM; its remote centre of motion in the world:
    "robot": {"urdf": "robots/psm.urdf",
              "base_pose": {"position": [0.10, 0.0, -0.02], "minus_z_toward": [0.0, 0.0, -0.2007]}},
    # in the world, looking along -z
    "camera": {"pose": [0.0, 0.0, -0.0507, 3.141592653589793, 0.0, 0.0],
               "intrinsics": {"fx": 769.0, "fy": 769.0, "cx": 320.0, "cy": 240.0, "width": 640,
                              "height": 480}},
    "start": {"joints": [-0.10, 0.05, 0.23, 0.20, 0.30, -0.20, 0.0]},  # [rad; m for the insertion]
    # camera frame: position [m], axis-angle [rad]
    "goal": {"pose": [-0.040, 0.018, 0.120, 0.037, 0.219, 2.226]},
    "horizon": 20,
}
"""The smallest problem `problem_from_dict` takes (problems/README.md, "A problem built in Python"):
the five required sections; noise, timing, limits, solver and the rest take their defaults (the
paper's constants)."""


def problem_from_dict(tree: dict, path: str | Path = "<python>") -> Problem:
    """A problem built in Python: `tree` as a problem file's YAML would give it
    (problems/README.md), NumPy arrays allowed. Relative URDF paths resolve as for a file in the
    current folder (the shipped `robots/...` from anywhere); errors name `path`, every error of the
    tree at once (`ProblemErrors` when there are several).

    Required: `robot`, `camera` (what the tracker sees is the problem's point, so it has no
    default), `start`, `goal` and `horizon`; the smallest is `MINIMAL_PROBLEM`:

        ss.problem_from_dict({
            "robot": {"urdf": "robots/psm.urdf",
                      "base_pose": {"position": [0.10, 0.0, -0.02],
                                    "minus_z_toward": [0.0, 0.0, -0.2007]}},
            "camera": {"pose": [0.0, 0.0, -0.0507, 3.141592653589793, 0.0, 0.0],
                       "intrinsics": {"fx": 769.0, "fy": 769.0, "cx": 320.0, "cy": 240.0,
                                      "width": 640, "height": 480}},
            "start": {"joints": [-0.10, 0.05, 0.23, 0.20, 0.30, -0.20, 0.0]},
            "goal": {"pose": [-0.040, 0.018, 0.120, 0.037, 0.219, 2.226]},
            "horizon": 20,
        })

    A pose is a list of 6 `[px, py, pz, rx, ry, rz]` (position [m], axis-angle [rad]) or
    `{"position": [...], "axis_angle": [...]}` (poses in the world also `rpy`, `minus_z_toward` or
    `matrix`)."""
    return parse_problem(plain_tree(tree), Path(path))


def read_yaml(path: Path) -> Any:
    """Parse a YAML file strictly (duplicate keys rejected); errors are one-line ProblemErrors."""
    try:
        if not path.is_file():
            raise ProblemError(str(path), None,
                               "no such file" if not path.exists() else "not a regular file")
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise ProblemError(str(path), None,
                               f"file of {size} bytes; at most {MAX_FILE_BYTES} are read")
        data = path.read_bytes()
    except OSError as exc:
        raise ProblemError(str(path), None,
                           f"cannot read the file ({exc.strerror or exc})") from None
    if b"\0" in data:
        raise ProblemError(str(path), None,
                           f"a binary file (NUL byte at offset {data.index(0)}), not YAML text")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ProblemError(str(path), None,
                           f"not UTF-8 text (invalid byte at offset {exc.start})") from None
    try:
        return yaml.load(text, Loader=_StrictLoader)  # a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ProblemError(str(path), None, f"not valid YAML{where}: {shown(what, 200)}") from None
    except RecursionError:
        raise ProblemError(str(path), None, "not valid YAML: nested too deeply "
                                            f"(at most {MAX_YAML_DEPTH} levels)") from None

