"""A command's PDE and settings: the ``--config`` TOML file's keys, then ``--set KEY=VALUE`` overrides; the CLI's
argument parser (``Parser``: defaults in --help, a bad option value answered in one line, ``usage_error``).

No JAX, no torch until a PDE is built (``pde_from_args``); a name is checked against ``catalog_names`` first.
"""

from __future__ import annotations

import argparse


def parse_sets(pairs: list[str] | None, option: str = "--set") -> dict[str, str]:
    """["nu=0.1", "ic.alpha=2"] -> {"nu": "0.1", "ic.alpha": "2"}; values stay strings for the PDE to parse. A key
    given twice with other values is refused (the last one won, silently: --set refine=2 --set refine=3); ``option``:
    the flag the pairs came from, for the messages."""
    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"bad {option} {pair!r}: expected KEY=VALUE, e.g. {option} "
                             + ("width=32" if option == "--model-set" else "nu=0.01"))
        key, value = key.strip(), value.strip()
        if out.get(key, value) != value:
            raise ValueError(f"{option} {key} given twice ({key}={out[key]} and {key}={value}); allowed: one value "
                             "per key")
        out[key] = value
    return out


def read_config(path: str) -> dict:
    """A TOML config file as a dict; one-line ValueError naming the file if unreadable, not UTF-8 or not TOML."""
    import tomllib

    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as err:
        raise ValueError(f"cannot read config {path}: {err.strerror}") from None
    except UnicodeDecodeError as err:  # tomllib decodes the whole file as UTF-8 first
        raise ValueError(f"config {path} is not UTF-8 text (byte {err.object[err.start]:#04x} at offset "
                         f"{err.start}); save it as UTF-8") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"config {path} is not valid TOML: {err}") from None


def settings_from_args(name: str | None, args: argparse.Namespace) -> tuple[str | None, dict]:
    """(PDE name, settings) from the command line: the --config file's keys, then --set overrides."""
    settings: dict = {}
    option = getattr(args, "pde_option", None)
    if name and option and name != option:
        raise ValueError(f"the command names PDE {name!r} and --pde {option!r}; give one")
    name = name or option
    if getattr(args, "config", None):
        data = read_config(args.config)
        # either a [pde] table (with name = NAME) or top-level keys (with pde = NAME)
        table = dict(data["pde"]) if isinstance(data.get("pde"), dict) else dict(data)
        file_name = table.pop("name", None) or table.pop("pde", None)
        if file_name is not None and not isinstance(file_name, str):
            raise ValueError(f"config {args.config}: the PDE name must be a string such as \"burgers1d\", "
                             f"got {file_name!r}")
        if name and file_name and name != file_name:
            raise ValueError(f"the command names PDE {name!r} but config {args.config} is for {file_name!r}")
        name = name or file_name
        ic = table.get("ic")
        if isinstance(ic, dict) and "kind" not in ic:  # TOML `ic.alpha = 2.5`: the same key as --set ic.alpha=2.5
            table.pop("ic")
            table.update({f"ic.{k}": v for k, v in ic.items()})
        settings.update(table)
    settings.update(parse_sets(getattr(args, "set", None)))
    return name or getattr(args, "pde_default", None), settings  # compare's burgers1d when nothing names a PDE


def build_pde(name, settings: dict | None = None):
    """The PDE ``name`` (a catalog entry, a user PDE, an import path; or a PDE object, returned as it is) with
    ``settings`` applied; one-line ValueError for an unknown name, checked before JAX is imported."""
    if name is not None and not isinstance(name, str):
        return name.replace(settings) if settings else name
    if name is None:
        raise ValueError("no PDE named: give one (see `pdestream list`) or a config with pde = NAME")
    from pdestream.catalog_names import check_name

    check_name(name)
    from pdestream import generator

    return generator.get_pde(name, settings)


def pde_from_args(name: str | None, args: argparse.Namespace, named: tuple[str | None, dict] | None = None):
    """The PDE named on the command line with --config then --set applied (``named``: the result of
    ``settings_from_args`` when the caller has it already, so the config file is read once)."""
    name, settings = settings_from_args(name, args) if named is None else named
    return build_pde(name, settings)


def usage_error(parser: argparse.ArgumentParser, message: str) -> str:
    """argparse's error ``message`` as the one line the CLI prints (``pdestream: error: ...``, no usage block): an
    int/float option given a non-number names the option, the value and what is allowed (with the option's default
    as the example); any other parse error keeps argparse's words. Ends with where the options are listed."""
    import re

    bad = re.fullmatch(r"argument (\S+?)(?:/\S+)?: invalid (int|float) value: (.*)", message)
    if bad:
        option, kind, value = bad.groups()
        action = parser._option_string_actions.get(option)
        default = getattr(action, "default", None)
        example = f", e.g. {option} {default}" if isinstance(default, (int, float)) and default is not True else ""
        what = "a whole number" if kind == "int" else "a number"
        message = f"{option} {value} not allowed; allowed: {what}{example}"
    return f"pdestream: error: {message} (`{parser.prog} --help` lists the options)\n"


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Adds "(default: X)" to an option's help unless it has none (None, a flag off, no list) or says it already."""

    def _get_help_string(self, action):
        none = action.default is None or action.default is False or action.default == []
        if none or "default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose --help shows defaults and whose errors are one line; subcommands' parsers too."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message):  # a bad value named with what is allowed, not argparse's usage block
        self.exit(2, usage_error(self, message))
