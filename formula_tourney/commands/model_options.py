"""Command-line options generated from a pydantic model's fields: one declaration per setting.

A setting that a model owns (a ``training.run_spec.Schedule`` key, a ``DemoSettings`` key, a
``RunSpec`` field) is declared, described, defaulted and validated there; a command lists the
model here and gets one typer option per field, so a new field appears in ``--help`` with no
edit in ``commands/``. The option's name is the field's (``test_starts`` -> ``--test-starts``,
after an optional prefix) unless the command keeps an older name for it; its help
text is the field's description and its shown default the field's default. A value counts as
given only when it came from the command line (click's parameter source), so the settings a
user left alone keep the preset's value, else the model's default. A given value is validated
by the field's own type and constraints, and a bad one is a UserInputError naming the option and
the model's message (which lists the allowed values).
"""

from __future__ import annotations

import inspect
import json
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Annotated, Any

import typer
from pydantic import BaseModel, TypeAdapter, ValidationError
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from formula_tourney.errors import UserInputError

_GIVEN = ("COMMANDLINE", "ENVIRONMENT")
"""Names of the click parameter sources of a value the user gave (not a default)."""


@dataclass(frozen=True)
class FieldOption:
    """One model field as one command-line option."""

    model: type[BaseModel]
    field: str
    name: str
    panel: str
    default: Any
    always: bool = False
    """Pass the value even when not given: the command's default of a field the model requires."""

    @property
    def param(self) -> str:
        """The callback's parameter name: unique across models (two may share a field name)."""
        return f"{self.model.__name__.lower()}__{self.field}"

    @property
    def info(self) -> FieldInfo:
        return self.model.model_fields[self.field]

    @property
    def is_flag(self) -> bool:
        return self.info.annotation is bool

    @property
    def repeatable(self) -> bool:
        return typing.get_origin(self.info.annotation) in (tuple, list)

    def parameter(self) -> inspect.Parameter:
        """The typer parameter: a ``--x/--no-x`` switch for a bool, a repeatable option for a
        tuple, else a string the field's validator parses."""
        decl = f"{self.name}/--no-{self.name[2:]}" if self.is_flag else self.name
        annotation: Any = bool if self.is_flag else list[str] if self.repeatable else str
        default = list(self.default or ()) if self.repeatable else self.default
        option = typer.Option(
            None if default is None else default, decl, help=self.info.description,
            metavar=None if self.is_flag else _metavar(self.info.annotation),
            show_default=default not in (None, []), rich_help_panel=self.panel,
        )  # fmt: skip
        return inspect.Parameter(self.param, inspect.Parameter.KEYWORD_ONLY, default=option,
                                 annotation=annotation)  # fmt: skip

    def validate(self, raw: Any) -> Any:
        """The value the field holds for ``raw`` (a string, list of strings or bool as click
        passes it); UserInputError naming the option when the field refuses it."""
        adapter = TypeAdapter(Annotated[(self.info.annotation, *self.info.metadata)]
                              if self.info.metadata else self.info.annotation)  # fmt: skip
        try:
            return adapter.validate_python(tuple(raw) if self.repeatable else raw)
        except ValidationError as err:
            parsed = [_json_or_none(r) for r in raw] if self.repeatable else _json_or_none(raw)
            if parsed is None or (self.repeatable and None in parsed):
                raise UserInputError(f"{self.name} {_shown(raw)}: {_messages(err)}") from None
            try:  # numbers a strict number type refuses as strings ("1.0" for a grip scale)
                return adapter.validate_python(tuple(parsed) if self.repeatable else parsed)
            except ValidationError as err2:
                raise UserInputError(f"{self.name} {_shown(raw)}: {_messages(err2)}") from None


def field_options(model: type[BaseModel], panel: str, *, prefix: str = "",
                  names: Mapping[str, str] | None = None,
                  defaults: Mapping[str, Any] | None = None,
                  skip: tuple[str, ...] = ()) -> list[FieldOption]:  # fmt: skip
    """One option per field of ``model`` (in declaration order) but those in ``skip``: named
    ``--PREFIX<field>`` (underscores as hyphens) unless ``names`` keeps an older name for it;
    its default is the field's, or ``defaults[field]`` for a field the model requires."""
    names, defaults = names or {}, defaults or {}
    out = []
    for name, info in model.model_fields.items():
        if name in skip:
            continue
        default = defaults.get(name, info.default)
        if default is PydanticUndefined:
            default = None
        option = names.get(name, f"--{prefix}{name.replace('_', '-')}")
        out.append(FieldOption(model, name, option, panel, default, always=name in defaults))
    return out


def with_field_options(command: Callable[..., Any], options: list[FieldOption]
                       ) -> Callable[..., Any]:  # fmt: skip
    """``command`` (whose own parameters end in ``**values``) with ``options`` appended to the
    signature typer reads; it receives them in ``values`` by :attr:`FieldOption.param`."""
    own = inspect.signature(command, eval_str=True)
    hints = typing.get_type_hints(command)
    params = [p for p in own.parameters.values() if p.kind is not inspect.Parameter.VAR_KEYWORD]
    generated = [o.parameter() for o in options]
    command.__signature__ = own.replace(parameters=[*params, *generated])  # type: ignore[attr-defined]
    command.__annotations__ = {**hints, **{p.name: p.annotation for p in generated}}
    return command


def chosen_values(ctx: typer.Context, options: list[FieldOption], values: Mapping[str, Any],
                  model: type[BaseModel]) -> dict[str, Any]:  # fmt: skip
    """The validated values of ``model``'s options, by field name: those the user gave on the
    command line, and the command's own defaults (``field_options``' ``defaults``). Options left
    alone are not in it, so the preset's value or the model's default holds."""
    return {o.field: o.validate(values[o.param]) for o in options
            if o.model is model and (o.always or ctx.get_parameter_source(o.param).name in _GIVEN)}


def _metavar(annotation: Any) -> str:
    """``[a|b]`` for a Literal, ``<int>`` / ``<float>`` / ``<str>`` for the others (the element
    type of a tuple, the type inside an optional)."""
    args = [a for a in typing.get_args(annotation) if a is not type(None) and a is not Ellipsis]
    if typing.get_origin(annotation) is typing.Literal:
        return "[" + "|".join(str(a) for a in args) + "]"
    if args:  # optional, tuple or Annotated: the type inside
        return _metavar(args[0])
    return f"<{getattr(annotation, '__name__', 'value')}>"


def _json_or_none(raw: str) -> Any:
    try:
        return json.loads(raw)
    except (json.JSONDecodeError, TypeError):
        return None


def _shown(raw: Any) -> str:
    return " ".join(str(r) for r in raw) if isinstance(raw, list) else str(raw)


def _messages(err: ValidationError) -> str:
    return "; ".join(str(e["msg"]) for e in err.errors())


def parse_key_values(items: list[str], what: str) -> dict[str, Any]:
    """``key=value`` pairs of a repeatable option such as ``--set``: values parse as JSON when
    they can (numbers, lists, booleans), else stay text; a pair without ``=`` is a
    UserInputError naming the option."""
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise UserInputError(f"{what} {item!r}: expected key=value")
        key, raw = item.split("=", 1)
        try:
            out[key.strip()] = json.loads(raw)
        except json.JSONDecodeError:
            out[key.strip()] = raw
    return out
