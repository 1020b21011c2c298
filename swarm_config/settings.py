"""Process settings, one way for every process: a YAML file, then the environment, then flags.

`LayeredSettings.from_sources` merges the three sources, lowest priority first, and validates the
result once; `describe_validation_error` is the project's one formatter of pydantic errors
for users: each problem on its own line, with the field's dotted path and, where the field can
come from the environment, its variable.
"""

from __future__ import annotations

import argparse
import math
import os
import types
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Self, Union, get_args, get_origin

import yaml
from pydantic import AfterValidator, BaseModel, ConfigDict, ValidationError

PROBLEM_LINE_CHARS_MAX = 300
"""The longest line one problem of a refused file or message gets: pydantic quotes some values
it refuses (a union's tag), and a 100 kB `kind` came back as 100 kB of error."""
PROBLEM_LINES_MAX = 50
"""The most problems listed one per line; the count of the rest follows."""


def describe_validation_error(
    heading: str, error: ValidationError, env: Mapping[str, str] | None = None
) -> str:
    """'heading (N problems):' then one line per problem: 'field.path (or $VAR): message',
    each cut in the middle to `PROBLEM_LINE_CHARS_MAX`, and at most `PROBLEM_LINES_MAX` of
    them."""
    count = error.error_count()
    lines = [f"{heading} ({count} problem{'s' if count != 1 else ''}):"]
    for item in error.errors(include_url=False)[:PROBLEM_LINES_MAX]:
        where = ".".join(str(p) for p in item["loc"]) or "(top level)"
        var = env.get(str(item["loc"][0])) if env and item["loc"] else None
        hint = f" (or ${var})" if var else ""
        message = item["msg"].removeprefix("Value error, ")
        line = f"  {where}{hint}: {message}"
        if len(line) > PROBLEM_LINE_CHARS_MAX:  # its start and its end name the problem
            keep = PROBLEM_LINE_CHARS_MAX // 2
            cut = len(line) - 2 * keep
            line = f"{line[:keep]}[... {cut:,} characters ...]{line[-keep:]}"
        lines.append(line)
    if count > PROBLEM_LINES_MAX:
        lines.append(f"  ... and {count - PROBLEM_LINES_MAX:,} more")
    return "\n".join(lines)


def describe_problems(heading: str, problems: Sequence[str]) -> str:
    """'heading (N problems):' then one line per problem, as `describe_validation_error`."""
    count = len(problems)
    lines = [f"{heading} ({count} problem{'s' if count != 1 else ''}):"]
    lines += [f"  {problem}" for problem in problems[:PROBLEM_LINES_MAX]]
    if count > PROBLEM_LINES_MAX:
        lines.append(f"  ... and {count - PROBLEM_LINES_MAX:,} more")
    return "\n".join(lines)


def _members(annotation: object) -> list[object]:
    """The types a field's annotation admits: Annotated unwrapped, unions flattened."""
    origin = get_origin(annotation)
    if origin is Annotated:
        return _members(get_args(annotation)[0])
    if origin is Union or origin is types.UnionType:
        return [m for arg in get_args(annotation) for m in _members(arg)]
    return [annotation]


def _model_for(members: list[object], value: Mapping[str, object]) -> type[BaseModel] | None:
    """The model among `members` that a mapping is for: the only one, or the one whose tag
    fields (`kind: circle`, `fault: kill`) it matches."""
    models = [m for m in members if isinstance(m, type) and issubclass(m, BaseModel)]
    for model in models:
        tags = {
            name: get_args(field.annotation)
            for name, field in model.model_fields.items()
            if get_origin(field.annotation) is Literal
        }
        if len(models) == 1 or all(
            name not in value or value[name] in allowed for name, allowed in tags.items()
        ):
            return model
    return None


def _booleans_in(annotation: object, value: object, where: str, problems: list[str]) -> None:
    members = _members(annotation)
    if isinstance(value, bool):
        if bool not in members and Any not in members and any(m in (int, float) for m in members):
            problems.append(f"{where}: a number, not {str(value).lower()}")
        return
    if isinstance(value, Mapping):
        model = _model_for(members, value)
        if model is not None:
            _booleans_in_model(model, value, f"{where}.", problems)
        return
    if not isinstance(value, list | tuple):
        return
    for member in members:
        if get_origin(member) not in (list, tuple, Sequence):
            continue
        args = get_args(member)
        per_item = get_origin(member) is tuple and (len(args) != 2 or args[1] is not Ellipsis)
        for i, item in enumerate(value):
            if per_item and i >= len(args):
                break
            element = args[i] if per_item else (args[0] if args else Any)
            _booleans_in(element, item, f"{where}.{i}", problems)
        return


def _booleans_in_model(
    model: type[BaseModel], data: Mapping[str, object], prefix: str, problems: list[str]
) -> None:
    for key, value in data.items():
        field = model.model_fields.get(key) if isinstance(key, str) else None
        if field is not None:
            _booleans_in(field.annotation, value, f"{prefix}{key}", problems)


def boolean_number_problems(model: type[BaseModel], data: object) -> list[str]:
    """'field.path: a number, not true' for every number field of `model` (nested models, lists
    and tuples included) that `data` gives a YAML boolean: pydantic takes true for 1 and false
    for 0 in an int or float field, so `seed: true` ran seed 1 and `duration_s: true` a 1 s run.
    Fields that admit a boolean, and keys the model does not know, are left to the model."""
    problems: list[str] = []
    if isinstance(data, Mapping):
        _booleans_in_model(model, data, "", problems)
    return problems


ENDPOINT_PROTOCOLS = ("tcp", "tls", "udp", "quic", "ws", "unixsock-stream")
"""The link protocols of a Zenoh endpoint `<protocol>/<address>[?<metadata>][#<config>]`."""


def endpoint_problem(endpoint: str) -> str | None:
    """Why `endpoint` is not an endpoint a process of the swarm can connect to or listen on, or
    None: Zenoh itself refuses such a text only when the config is loaded, with a traceback in
    Rust's words, or (a client) keeps trying to reach it."""
    protocol, slash, rest = endpoint.partition("/")
    address = rest.split("?", 1)[0].split("#", 1)[0]
    if not slash or not address:
        return f"{endpoint!r} is not <protocol>/<address>, e.g. tcp/127.0.0.1:7447"
    if protocol not in ENDPOINT_PROTOCOLS:
        return f"{endpoint!r}: no protocol {protocol!r}; use one of {', '.join(ENDPOINT_PROTOCOLS)}"
    if protocol == "unixsock-stream":
        return None
    host, colon, port = address.rpartition(":")
    if not colon or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        return f"{endpoint!r}: the address is not HOST:PORT with a port in 1-65535"
    return None


def _checked_endpoints(endpoints: list[str]) -> list[str]:
    for endpoint in endpoints:
        problem = endpoint_problem(endpoint)
        if problem is not None:
            raise ValueError(problem)
    return endpoints


Endpoints = Annotated[list[str], AfterValidator(_checked_endpoints)]
"""A process's `connect` setting: Zenoh endpoints, each checked (`endpoint_problem`)."""


def endpoint_list(text: str) -> str:
    """An argparse type: one endpoint or a comma-separated list, each checked
    (`endpoint_problem`); the text as given."""
    endpoints = [part.strip() for part in text.split(",") if part.strip()]
    if not endpoints:
        raise argparse.ArgumentTypeError(f"{text!r} names no endpoint, e.g. tcp/127.0.0.1:7447")
    try:
        _checked_endpoints(endpoints)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def tcp_port(text: str) -> int:
    """A command line's TCP port (1-65535), for argparse's `type=`: anything else is a usage
    error naming the value, before a process is started that would fail to listen on it."""
    try:
        port = int(text)
    except ValueError:
        port = 0
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a TCP port (1-65535)")
    return port


def positive_seconds(text: str) -> float:
    """A command line's time-out in seconds, for argparse's `type=`: a finite number above 0."""
    try:
        seconds = float(text)
    except ValueError:
        seconds = math.nan
    if not (math.isfinite(seconds) and seconds > 0.0):
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds above 0")
    return seconds


class SettingsError(ValueError):
    """Settings that cannot be used; the message names the field (and its variable)."""


PROJECT_ROOT = Path(__file__).resolve().parents[1]
"""The folder of the project's sources and its `configs/` (every install is editable)."""
DEFAULT_SCENARIO_PATH = PROJECT_ROOT / "configs" / "scenarios" / "paper.yaml"
"""The paper's experiment, what runs when no scenario is given: the project's own file, from
whatever folder a command runs in (a scenario a user names is found from that folder)."""


class ScenarioError(Exception):
    """A scenario file that cannot be used; the message is meant for the user.  It lives here,
    with the settings errors, so that a command that reports one need not load the scenario
    models (and the control kernels behind them)."""


_SafeLoader: type[yaml.SafeLoader] = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
"""PyYAML's safe loader on libyaml (C) where the installed PyYAML has it (its wheels do), about
ten times faster than the pure-Python one (a robot's `params` verb, the fuzz tests of every file
format).  Valid files load to the same data; libyaml is the more lenient of the two on a few
malformed inputs (a tab inside a plain scalar, a byte-order mark between lines), which the
models behind every loader then judge like any other value."""


_MERGE_KEY_TAG = "tag:yaml.org,2002:merge"

YAML_EXPANDED_NODES_MAX = 1_000_000
"""The most values (scalars, lists and mappings) a YAML document may stand for once every
alias is replaced by what it refers to.  Aliases let a few hundred bytes stand for billions of
values (each of ten lists holding the one before ten times, the "billion laughs"): PyYAML
builds them as shared references at once, but whatever walks the data after it visits each
reference: a scenario whose trajectory `kind` was 10**7 values in 428 bytes of aliases took 13 s
to refuse, with 358 MB of error text quoting the tag.  A generated scenario of 256 robots is
some 4,400 values; a 1 MiB message of plain text some 500,000."""


def _expanded_node_count(root: yaml.Node, limit: int) -> int:
    """How many nodes `root` stands for with every alias expanded, counting up to `limit + 1`
    and stopping there.  yaml.YAMLError for a node that holds itself (`&a [*a]`).  A list or
    mapping met again is counted from a memo, so the walk is linear in the document."""
    expanded: dict[int, int] = {}
    open_nodes: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        if not isinstance(node, yaml.CollectionNode):
            expanded[id(node)] = 1
            continue
        children: list[yaml.Node] = (
            [part for pair in node.value for part in pair]
            if isinstance(node, yaml.MappingNode)
            else node.value
        )
        if children_done:
            open_nodes.discard(id(node))
            total = 1
            for child in children:
                total += expanded[id(child)] if isinstance(child, yaml.CollectionNode) else 1
            expanded[id(node)] = min(limit + 1, total)
            continue
        if id(node) in expanded:
            continue
        if id(node) in open_nodes:  # every open node is an ancestor of what the stack holds
            raise yaml.composer.ComposerError(
                None, None, "found an alias inside the node it refers to", node.start_mark
            )
        open_nodes.add(id(node))
        stack.append((node, True))
        stack.extend(
            (child, False)
            for child in children
            if isinstance(child, yaml.CollectionNode) and id(child) not in expanded
        )
    return expanded[id(root)]


class _UniqueKeySafeLoader(_SafeLoader):  # type: ignore[misc,valid-type]  # a base chosen at import
    """`_SafeLoader` that refuses a mapping holding one key twice, and a document whose aliases
    expand beyond `YAML_EXPANDED_NODES_MAX` values.  PyYAML keeps the last of two equal keys
    silently, so a scenario with `duration_s` written twice ran the second one and a
    parameter file's repeated key hid the first value.  Keys a merge (`<<: *anchor`) brings in
    are not repeats: the mapping's own keys override them, as YAML says."""

    def get_single_data(self) -> object:
        node = self.get_single_node()
        if node is None:
            return None
        if _expanded_node_count(node, YAML_EXPANDED_NODES_MAX) > YAML_EXPANDED_NODES_MAX:
            raise yaml.composer.ComposerError(
                None,
                None,
                f"its aliases expand to more than {YAML_EXPANDED_NODES_MAX:,} values",
                node.start_mark,
            )
        return self.construct_document(node)

    def construct_mapping(self, node: yaml.Node, deep: bool = False) -> dict[object, object]:
        if isinstance(node, yaml.MappingNode):
            first_seen: dict[object, yaml.Node] = {}
            for key_node, _ in node.value:
                if key_node.tag == _MERGE_KEY_TAG:
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = first_seen.setdefault(key, key_node)
                except TypeError:  # an unhashable key, which the base constructor refuses
                    continue
                if first is not key_node:
                    raise yaml.constructor.ConstructorError(
                        "while constructing a mapping",
                        node.start_mark,
                        f"found the key {key!r} twice (first on line {first.start_mark.line + 1})",
                        key_node.start_mark,
                    )
        mapping: dict[object, object] = super().construct_mapping(node, deep=deep)
        return mapping


def parse_yaml(text: str | bytes) -> object:
    """`yaml.safe_load` of `text`, on libyaml where available (`_SafeLoader`), refusing a key
    written twice in one mapping (`_UniqueKeySafeLoader`).  Raises what safe_load raises:
    yaml.YAMLError (a repeated key included), ValueError (an impossible date),
    RecursionError."""
    return yaml.load(text, Loader=_UniqueKeySafeLoader)


INPUT_FILE_BYTES_MAX = 8 << 20
"""The largest scenario, campaign, fuzzy parameter or settings file read.  A generated scenario
of 256 robots is some 40 KiB; a larger file, or an endless one such as /dev/zero, is refused
before it fills the memory."""


def read_input_file(path: Path, what: str, limit_bytes: int = INPUT_FILE_BYTES_MAX) -> bytes:
    """The bytes of a file a user names, at most `limit_bytes` of them; SettingsError naming
    the file when it cannot be read or is larger."""
    try:
        with path.open("rb") as handle:
            data = handle.read(limit_bytes + 1)
    except OSError as exc:
        raise SettingsError(f"{path}: cannot read {what} ({exc.strerror})") from None
    if len(data) > limit_bytes:
        raise SettingsError(f"{path}: {what} is larger than {limit_bytes:,} bytes")
    return data


def read_yaml(path: Path, what: str) -> object:
    """The data of a YAML (or JSON) file; SettingsError naming the file and the problem for
    anything else: unreadable, too large, not UTF-8, not YAML, nested too deep, an impossible
    date."""
    try:
        text = read_input_file(path, what).decode("utf-8")
    except UnicodeDecodeError:
        raise SettingsError(f"{path}: {what} is not UTF-8 text") from None
    try:
        return parse_yaml(text)
    except RecursionError:
        raise SettingsError(f"{path}: {what} is nested too deeply") from None
    except (yaml.YAMLError, ValueError) as exc:  # ValueError: e.g. a date like 2001-02-30
        raise SettingsError(f"{path}: {what} is not valid YAML: {exc}") from None


def read_yaml_mapping(path: Path, what: str) -> dict[str, Any]:
    """A YAML file that must hold a mapping (empty file: {}); SettingsError otherwise."""
    loaded = read_yaml(path, what)
    if loaded is None:
        return {}
    if not isinstance(loaded, dict):
        raise SettingsError(f"{path}: {what} must be a YAML mapping")
    return loaded


class LayeredSettings(BaseModel):
    """Base of a process's settings.  Subclasses name their environment variables in `ENV`
    (field -> variable) and may parse a variable's text in `ENV_PARSERS`.  No float setting
    takes NaN or infinity (`--duration inf` is refused, naming the field); subclasses' own
    `model_config` adds to this one."""

    model_config = ConfigDict(allow_inf_nan=False)

    ENV: ClassVar[Mapping[str, str]] = {}
    ENV_ALIASES: ClassVar[Mapping[str, str]] = {}
    """Field -> a second variable read when the first is unset (e.g. ROBOT_ID)."""
    ENV_PARSERS: ClassVar[Mapping[str, Callable[[str], object]]] = {}
    WHAT: ClassVar[str] = "settings"

    @classmethod
    def from_sources(
        cls,
        given: Mapping[str, Any],
        environ: Mapping[str, str] | None = None,
        config_file: Path | None = None,
    ) -> Self:
        """Settings from a YAML file, then environment variables, then `given` (the command
        line; None values are not given), each overriding the one before.

        Raises SettingsError naming every bad field (and its variable)."""
        env = os.environ if environ is None else environ
        values: dict[str, Any] = {}
        if config_file is not None:
            values.update(read_yaml_mapping(config_file, cls.WHAT))
        for key, var in cls.ENV.items():
            raw = env.get(var)
            if not raw and key in cls.ENV_ALIASES:
                raw = env.get(cls.ENV_ALIASES[key])
            if raw:
                parse = cls.ENV_PARSERS.get(key)
                values[key] = parse(raw) if parse is not None else raw
        values.update({k: v for k, v in given.items() if v is not None})
        try:
            return cls.model_validate(values)
        except ValidationError as exc:
            raise SettingsError(
                describe_validation_error(f"invalid {cls.WHAT}", exc, cls.ENV)
            ) from None
