"""One way to read a `morphmimic` command's options: a dataclass parsed by tyro.

Each command declares its options as one dataclass whose field docstrings are the `--help`
texts, with the numeric fields' allowed ranges in `LIMITS` (`common.config_limits`) and any
other check in `validate()`. `parse_options` returns the filled dataclass or ends the process
with one line on stderr naming the value and what is allowed, exit 2:

    @validated
    @dataclass
    class Options:
        checkpoint: str
        \"\"\"A run directory or a state.pt.\"\"\"
        starts: int = 10
        \"\"\"Starts per clip.\"\"\"
        LIMITS: ClassVar[dict[str, Limit]] = {"starts": at_least(1)}
        FLAG_PREFIX: ClassVar[str] = ""

        def validate(self) -> None:
            check_limits(self)

    opts = parse_options(Options, argv, prog="morphmimic evaluate", description=__doc__)
"""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import inspect
import io
import sys
import textwrap
from collections.abc import Callable
from typing import Annotated, Any, Literal, NoReturn, TypeVar, get_args, get_origin, get_type_hints

import tyro
from tyro.constructors import PrimitiveConstructorSpec

from common.config_limits import deferred_checks, validate_tree

T = TypeVar("T")


def comma_list(item: Callable[[str], Any], example: str, what: str = "comma-separated values") -> PrimitiveConstructorSpec:
    """One flag value holding comma-separated items (`--widths 128,256`) read as a tuple of
    `item(text)`; an empty value or an item `item` refuses (ValueError) is a parse error naming
    the value: "'40,many': give <what>, e.g. <example>"."""

    def parse(args: list[str]) -> tuple:
        parts = [x.strip() for x in args[0].split(",") if x.strip()]
        try:
            if parts:
                return tuple(item(x) for x in parts)
        except ValueError:
            pass
        raise ValueError(f"{args[0]!r}: give {what}, e.g. {example}")

    return PrimitiveConstructorSpec(nargs=1, metavar=example.upper() if example.isalpha() else example,
                                    instance_from_str=parse, is_instance=lambda v: isinstance(v, tuple),
                                    str_from_instance=lambda v: ["None" if v is None else ",".join(map(str, v))])


def value_list(item: Callable[[str], Any], metavar: str, show: Callable[[Any], str] = str,
               nargs: str = "*") -> PrimitiveConstructorSpec:
    """A flag taking several values (`--stitch a b`, `--keys 1:left 3:faster`) read as a tuple of
    `item(text)`; the message of a ValueError `item` raises is the parse error, so it should name
    the value and its form. `show` writes an item back (the default in --help); `nargs="+"`
    refuses the flag without a value."""
    return PrimitiveConstructorSpec(nargs=nargs, metavar=metavar,
                                    instance_from_str=lambda args: tuple(item(x) for x in args),
                                    is_instance=lambda v: isinstance(v, tuple),
                                    str_from_instance=lambda v: [show(x) for x in v])


CommaInts = Annotated[tuple[int, ...], comma_list(int, "1,2,4", "comma-separated integers")]
"""`--actors 1,2,4`: integers in one comma-separated value (limits check each)."""
CommaFloats = Annotated[tuple[float, ...], comma_list(float, "0.5,1.0", "comma-separated numbers")]
"""`--lengths 5,20`: numbers in one comma-separated value."""
CommaStrs = Annotated[tuple[str, ...], comma_list(str, "a,b", "comma-separated names")]
"""`--presets reach,executor`: names in one comma-separated value."""


def scan_flag(argv: list[str], name: str, default: str) -> tuple[str, list[str]]:
    """The value of `--name VALUE` or `--name=VALUE` in `argv` (the last one given, else
    `default`) and `argv` without it: an option that picks the other options' defaults (`--preset`).
    Raises ValueError when the flag ends `argv` without a value."""
    value, rest, i = default, [], 0
    while i < len(argv):
        arg = argv[i]
        if arg == "--":
            rest += argv[i:]
            break
        if arg == name:
            if i + 1 >= len(argv):
                raise ValueError(f"{name} expects a value")
            value, i = argv[i + 1], i + 2
            continue
        if arg.startswith(name + "="):
            value = arg[len(name) + 1:]
        else:
            rest.append(arg)
        i += 1
    return value, rest


def one_line(box: str) -> str:
    """tyro's boxed parse error as one line: its message, then the expected form or the flag it
    suggests (`--ppo.lr abc` -> "Error parsing --ppo.lr: could not convert string to float:
    'abc'; expected: --ppo.lr FLOAT")."""
    lines = [line for line in box.splitlines() if line.strip()]
    title = ""
    if len(lines) >= 2 and lines[0].lstrip()[:1] in ("╭", "+", "-"):
        title = lines[0].strip().strip("╭╮+-─ ").strip()
        lines = lines[1:-1]  # the top border (with the box's title) and the bottom one
    rows = [line.strip().strip("│|").strip() for line in lines]
    sections, current = [], []
    for row in rows:
        if not row:
            continue
        if set(row) <= set("─-=+"):
            sections.append(current)
            current = []
        else:
            current.append(row)
    sections.append(current)
    sections = [sec for sec in sections if sec and not sec[0].startswith("For full helptext")]
    if not sections and title:
        return title  # the message is the title ("Missing value for argument '--stages'. ...")
    if len(sections) > 1 and len(sections[0]) == 1 and len(sections[0][0]) < 40 and not set(sections[0][0]) & set(":'\""):
        sections = sections[1:]  # a plain-text box's title ("Value error") on a row of its own
    if not sections:
        return box.strip() or "invalid arguments"
    text = " ".join(sections[0])
    for sec in sections[1:]:
        if sec[0].startswith(("Argument helptext", "Perhaps you meant")) and len(sec) > 1:
            text += ("; expected: " if sec[0].startswith("Argument") else "; did you mean: ") + sec[1]
    return text


def field_docs(cls: type) -> dict[str, str]:
    """Each field's docstring (the string right after it in the class body, as tyro reads it),
    base classes first, by field name; fields without one are left out."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__[:-1]):
        try:
            body = ast.parse(textwrap.dedent(inspect.getsource(klass))).body[0].body
        except (OSError, TypeError, IndexError, AttributeError):
            continue
        for node, after in zip(body, body[1:]):
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and isinstance(after, ast.Expr) \
                    and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str):
                docs[node.target.id] = inspect.cleandoc(after.value.value)
    return docs


def short_help(cls: type, names: list[str], defaults: Any, prog: str, head: str = "", extra: list[tuple[str, str]] = (),
               more: str = "--help-all") -> str:
    """A short --help: the usage line, `head`, then the fields `names` of dataclass `cls` as flags
    with their values (a Literal's choices), defaults (from `defaults`, an instance) and field
    docstrings, `extra` (flag, text) rows first; ends with a line naming `more` for every option.
    Built from the dataclass, so it cannot drift from the parser."""
    hints, docs = get_type_hints(cls), field_docs(cls)
    fields = {f.name for f in dataclasses.fields(cls)}
    rows = list(extra)
    for name in names:
        if name not in fields:
            raise ValueError(f"{cls.__name__} has no field {name!r}")
        hint, value = hints[name], getattr(defaults, name)
        flag = "--" + name.replace("_", "-")
        if get_origin(hint) is Literal:
            flag += " {" + ",".join(map(str, get_args(hint))) + "}"
        elif hint is bool:
            flag += " / --no-" + name.replace("_", "-")
        else:
            flag += " " + getattr(hint, "__name__", "VALUE").upper()
        text = " ".join(docs.get(name, "").split())
        rows.append((flag, f"{text} (default: {value!r})" if not isinstance(value, str) or value else f"{text} (default: '')"))
    width = min(max(len(f) for f, _ in rows), 36)
    lines = [f"usage: {prog} [OPTIONS]", ""] + ([head.rstrip(), ""] if head else []) + ["common options:"]
    for flag, text in rows:
        wrapped = textwrap.wrap(text, 100 - width - 4) or [""]
        if len(flag) > width:
            lines.append(f"  {flag}")
            lines += [" " * (width + 4) + w for w in wrapped]
        else:
            lines.append(f"  {flag:<{width}}  {wrapped[0]}")
            lines += [" " * (width + 4) + w for w in wrapped[1:]]
    lines += ["", f"{more} shows every option (the task, policy, PPO, actors, sampler, ...) with its default."]
    return "\n".join(lines)


def parse_options(cls: type[T], argv: list[str], prog: str, description: str | None = None,
                  default: T | None = None, **tyro_kwargs: Any) -> T:
    """`cls` filled from `argv` by tyro (field docstrings as help), its checks run after parsing
    (`validate_tree`: every nested dataclass's `validate`). A parse error or a failed check is
    one line `prog: ...` on stderr and SystemExit(2); `--help` exits 0 as usual."""
    errors = io.StringIO()
    try:
        with deferred_checks(), contextlib.redirect_stderr(errors):
            opts = tyro.cli(cls, args=list(argv), prog=prog, description=description, default=default, **tyro_kwargs)
    except SystemExit as exc:
        if exc.code:
            print(f"{prog}: {one_line(errors.getvalue())}", file=sys.stderr)
        raise
    try:
        validate_tree(opts)
    except ValueError as exc:
        print(f"{prog}: invalid configuration: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    return opts


def refuse(prog: str, message: str) -> NoReturn:
    """End the command as a usage error found after parsing (a file that exists, a value the
    data refuses): one line `prog: message` on stderr, exit 2."""
    print(f"{prog}: {message}", file=sys.stderr)
    raise SystemExit(2)
